"""The online labeller on other performers' clips (`styleerd eval labels`), and its training with
them: the clips it is measured on are never trained on, and the unsure loss of a style the model
does not have is smallest where the posterior is uniform."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from styleerd.data.datasets import bandai1_kept_back
from styleerd.data.outside import held_out
from styleerd.train.labeller import FAMILIAR_EDGES, labeller_loss


def test_the_labeller_loss_is_the_cross_entropy_and_uniform_for_styles_the_model_lacks():
    torch.manual_seed(0)
    s, c = torch.randn(4, 7, 5), torch.randn(4, 7, 3)
    style, content = torch.tensor([0, 4, 2, 1]), torch.tensor([2, 0, 1, 1])
    plain = F.cross_entropy(s.reshape(-1, 5), style.repeat_interleave(7)) + F.cross_entropy(
        c.reshape(-1, 3), content.repeat_interleave(7)
    )
    assert torch.allclose(labeller_loss(s, c, style, content, 0.5), plain)  # every label known: as before
    unknown, untold = torch.tensor([-1, -1, -1, -1]), torch.tensor([-1, -1, -1, -1])
    uniform = labeller_loss(torch.zeros(4, 7, 5), c, unknown, untold, 0.5)
    assert torch.isclose(uniform, torch.tensor(0.5 * np.log(5), dtype=torch.float32))
    assert labeller_loss(s, c, unknown, untold, 0.5) > uniform  # any sure posterior costs more
    mixed = labeller_loss(s, c, torch.tensor([0, -1, 2, -1]), torch.tensor([2, -1, 1, -1]), 0.5)
    assert torch.isfinite(mixed)


@pytest.mark.slow
def test_the_clips_measured_on_are_never_trained_on_and_the_neutral_walk_reads_normal(shared_data):
    from styleerd.eval.labels import clip_figures, outside_clips
    from styleerd.model.stored import load_generator_weights

    clips = outside_clips(str(shared_data))
    groups = {c.group for c in clips}
    assert groups == {"xia-sample", "cmu-sample iclone", "cmu-sample asf-names", "bandai-namco-1 kept back"}
    for c in clips:  # the training's own exclusion rules (train.batches.outside_clips) cover every one
        if c.group.startswith("cmu"):
            assert held_out(c.name.removeprefix("cmu "), "cmu-sample"), c.name
        elif c.group.startswith("bandai"):
            content = c.name.split("_")[1]
            assert bandai1_kept_back(c.name, content), c.name
    model = load_generator_weights()
    walk = next(c for c in clips if c.name.startswith("neutral_01"))
    figures = clip_figures(model, walk)
    assert figures["read"][0] == "normal" and figures["confident_wrong"] == 0.0, figures
    # styles the model lacks, read with confidence as masculine or active on 49 and 55 % of their
    # frames before the labeller knew where its states are familiar (docs/model.md)
    for name in ("dataset-1_byebye_giant_001", "dataset-1_dash_proud_001"):
        figures = clip_figures(model, next(c for c in clips if c.name == name))
        assert figures["confident_wrong"] <= 0.05 and figures["right_or_neutral"] >= 0.8, (name, figures)


def test_the_transfer_summary_says_how_much_of_the_input_the_labeller_could_not_read(shared_data):
    """Another performer's `old` walk is mostly unlike the labeller's training streams, a
    Bandai-Namco-2 test clip is not; given the input's style, the line is not there."""
    from styleerd.data.datasets import find_clips, load_motion
    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime.offline import TransferOptions, transfer_motion
    from styleerd.train.config import TrainConfig
    from styleerd.train.trainer import setup

    model = load_generator_weights()
    s = setup(TrainConfig(), str(shared_data), progress=False)
    test_clip = s.fs.motion(int(s.fs.clips("test")[0]))
    xia_old = load_motion(next(c for c in find_clips(shared_data, "xia-sample") if c.name == "old_13_000"))

    def unread(motion, input_style=None) -> list[str]:
        lines: list[str] = []
        transfer_motion(motion, model, motion.fps, TransferOptions({"youthful": 1.0}, input_style), report=lines.append)
        return [line for line in lines if "unlike any the labeller learnt" in line]

    def share(line: str) -> int:
        return int(line.split(": ")[1].split(" %")[0])

    assert share(unread(xia_old)[0]) >= 60 and share(unread(test_clip)[0]) <= 5
    assert unread(xia_old, "elderly") == []


@pytest.mark.slow
def test_train_labeller_fine_tunes_with_other_performers_and_records_what_it_did(shared_data, tmp_path):
    """``styleerd train-labeller`` as configs/labeller-outside.yaml runs it, on a few clips: the
    fine-tuning starts from the saved labeller, takes other performers' clips with the configured
    unsure weight, and its test record is what the saved labeller gives again."""
    from pathlib import Path

    from styleerd.model import checkpoint as ckpt
    from styleerd.train.config import TrainConfig
    from styleerd.train.labeller import stream_accuracy, train_and_save
    from styleerd.train.trainer import setup

    start = Path(__file__).parents[1] / "models" / "labellers" / "labeller-bandai2-scratch"
    config = TrainConfig(
        max_train_clips=40,
        threads=1,
        labeller_init_from=str(start),
        labeller_outside=True,
        labeller_epochs=1,
        labeller_lr=1e-4,
        labeller_unsure=1.5,
    )
    train_and_save(config, str(shared_data), tmp_path / "labeller", progress=False)
    labeller, meta = ckpt.load_labeller(tmp_path / "labeller")
    assert meta["started_from"] == str(start) and len(meta["history"]) == 1
    assert meta["outside"]["unsure_weight"] == 1.5 and meta["outside"]["clips"] > 100
    s = setup(config, str(shared_data), progress=False)
    assert {str(k): v for k, v in stream_accuracy(labeller, s.fs, s.data, "test").items()} == meta["test"]
    assert meta["test"]["30"]["style"] > 0.9  # a short fine-tuning from a good labeller keeps it good
    # where its states are familiar is measured and saved with it, and the record leaning to
    # neutral is what the saved labeller gives again with it
    f = labeller.familiar
    assert f is not None and meta["familiar"]["edges"] == list(FAMILIAR_EDGES) and np.all(f.near < f.far)
    leaning = stream_accuracy(labeller, s.fs, s.data, "test", neutral=config.neutral_style)
    assert {str(k): v for k, v in leaning.items()} == meta["test_leaning_neutral"]
    assert leaning[30]["style"] > 0.9


@pytest.mark.parametrize("bad", [(99.9, 99.0), (99.0,), ("a", 99.0), (0.0, 50.0), (50.0, 101.0)])
def test_labeller_familiar_must_be_two_rising_percentiles_or_none(bad, tmp_path):
    from styleerd.errors import StyleERDError
    from styleerd.train.config import TrainConfig
    from styleerd.train.labeller import train_and_save

    with pytest.raises(StyleERDError, match="labeller_familiar must be two percentiles"):
        train_and_save(TrainConfig(labeller_familiar=bad), None, tmp_path / "lab", progress=False)


def test_familiarity_is_the_mahalanobis_distance_to_the_nearest_style_mean_of_the_streams_group():
    from scipy.spatial.distance import mahalanobis

    from styleerd.model.stored import Familiarity, familiarity

    rng = np.random.default_rng(0)
    H, S, edges = 6, 3, np.array([1, 4])
    A = rng.normal(size=(H, H))
    cov = A @ A.T + np.eye(H)
    means = rng.normal(size=(3, S, H))
    whiten = np.linalg.cholesky(np.linalg.inv(cov))
    near, far = np.array([1.0, 2.0, 3.0]), np.array([2.0, 4.0, 5.0])
    f = Familiarity.from_arrays(
        {
            "familiar.edges": edges,
            "familiar.whiten": whiten,
            "familiar.means": means @ whiten,
            "familiar.near": near,
            "familiar.far": far,
        },
        H,
        S,
    )
    state = (rng.normal(size=(40, H)) * 2).astype(np.float32)
    frames = rng.integers(0, 9, size=40)
    distance = np.empty(40)
    trust = familiarity(state, frames, f, distance)
    group = np.where(frames < 1, 0, np.where(frames < 4, 1, 2))
    VI = np.linalg.inv(cov)
    expected = [min(mahalanobis(x, m, VI) for m in means[g]) for x, g in zip(state, group)]
    assert np.allclose(distance, expected, rtol=1e-4)
    assert np.allclose(trust, np.clip((far[group] - distance) / (far[group] - near[group]), 0, 1), atol=1e-5)
    assert 0 < (trust == 1).sum() < 40 and 0 < (trust == 0).sum() < 40  # both ends and the ramp reached


def test_an_unfamiliar_state_tells_the_neutral_style_whatever_the_posterior():
    from styleerd.model.stored import toward_neutral

    p = np.array([[0.97, 0.01, 0.02], [0.97, 0.01, 0.02], [0.97, 0.01, 0.02], [0.3, 0.3, 0.4]])
    told = toward_neutral(p, 2, np.array([1.0, 0.0, 0.5, 1.0]))
    assert np.allclose(told[0], toward_neutral(p[:1], 2)[0])  # familiar: as without the measure
    assert np.allclose(told[1], [0, 0, 1])
    assert np.allclose(told[2], [0.485, 0, 0.515])  # half kept; the 0.005 left of the second is absent
    assert np.allclose(told[3], [0, 0, 1])  # unsure anyway


@pytest.mark.parametrize(
    "change, problem",
    [
        ({"familiar.means": np.zeros((6, 7, 5), np.float32)}, "familiar.means has shape (6, 7, 5)"),
        ({"familiar.near": np.full(6, 99.0, np.float32)}, "0 <= near < far"),
        ({"familiar.whiten": np.full((64, 64), np.nan, np.float32)}, "must be finite"),
        ({"familiar.edges": np.array([1, 1, 4, 8, 16])}, "increasing frame counts"),
    ],
)
def test_a_labeller_file_with_a_broken_familiarity_is_a_clear_error(tmp_path, change, problem):
    from safetensors import safe_open
    from safetensors.numpy import load_file, save_file

    from styleerd.errors import StyleERDError
    from styleerd.model.stored import load_labeller_weights
    from styleerd.models import MODELS_DIR

    source = MODELS_DIR / "labeller-bandai2.safetensors"
    with safe_open(str(source), "np") as f:
        header = f.metadata()  # the labeller's configuration, kept
    save_file({**load_file(source), **change}, tmp_path / "lab.safetensors", metadata=header)
    with pytest.raises(StyleERDError, match="cannot load model .*lab.safetensors") as e:
        load_labeller_weights(tmp_path / "lab")
    assert problem in str(e.value), e.value


@pytest.mark.slow
def test_the_familiarity_sweep_refits_the_shipped_weights_and_its_shipped_row_is_the_shipped_labeller(
    shared_data, tmp_path
):
    """benchmarks/familiar_sweep.py: no measure, and the shipped percentiles, side by side. The
    shipped row's Bandai-Namco-2 record is the shipped labeller's own (the same weights, the same
    fit); without the measure Bandai-Namco-1's frames are told a confident wrong style at least twice
    as often."""
    import json
    import subprocess
    import sys

    from styleerd.model import checkpoint as ckpt

    out = tmp_path / "sweep.json"
    done = subprocess.run(
        [sys.executable, "benchmarks/familiar_sweep.py", "--pairs", "99,99.9", "--json", str(out)]
        + ["--data", str(shared_data)],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    rows = json.loads(out.read_text())
    assert list(rows) == ["none", "99 / 99.9"] and "| 99 / 99.9 |" in done.stdout
    assert rows["99 / 99.9"]["test_leaning_neutral"] == ckpt.load_labeller()[1]["test_leaning_neutral"]
    wrong = {k: r["groups"]["bandai-namco-1 kept back"]["confident_wrong"] for k, r in rows.items()}
    assert wrong["none"] > 2 * wrong["99 / 99.9"], wrong
