"""Training on real data with tiny configs: resume after kill -9, data parallel, ablations."""

import csv
import os
import signal
import subprocess
import sys
import time

import pytest
import torch
import yaml

from styleerd.errors import StyleERDError
from styleerd.model import checkpoint as ckpt
from styleerd.model import torch_quat
from styleerd.train.config import TrainConfig

pytestmark = pytest.mark.slow

TINY = {
    "max_train_clips": 40,
    "neutral_layers": 2,
    "style_layers": 1,
    "batch_size": 16,
    "val_windows": 64,
    "classifier_epochs": 1,
    "threads": 1,
    "val_every": 1,
}


def write_config(path, **kw):
    path.write_text(yaml.safe_dump({**TINY, **kw}))
    return path


def run_cli(*args, env=None, **kw):
    return subprocess.Popen(
        [sys.executable, "-m", "styleerd.cli", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        **kw,
    )


def epochs_done(out):
    p = out / "metrics.csv"
    return len(list(csv.DictReader(open(p)))) if p.is_file() else 0


def test_kill_9_mid_run_then_rerun_continues_and_matches_an_uninterrupted_run(shared_data, tmp_path):
    cfg = write_config(tmp_path / "c.yaml", epochs=6, ema=0.9)  # the weights' moving average resumes too
    straight = run_cli("train", "--config", cfg, "--out", tmp_path / "a")
    assert straight.wait(timeout=600) == 0, straight.stdout.read()

    proc = run_cli("train", "--config", cfg, "--out", tmp_path / "b")
    deadline = time.time() + 600
    while not (tmp_path / "b" / "checkpoint.safetensors").is_file() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done = epochs_done(tmp_path / "b")
    assert 1 <= done < 6, "the kill should land mid-run"
    again = run_cli("train", "--config", cfg, "--out", tmp_path / "b")
    log, _ = again.communicate(timeout=600)
    assert again.returncode == 0, log
    assert f"resuming {tmp_path / 'b'} after epoch {done}" in log
    assert epochs_done(tmp_path / "b") == 6
    a, _ = ckpt.load_tensors(tmp_path / "a" / "checkpoint")
    b, _ = ckpt.load_tensors(tmp_path / "b" / "checkpoint")
    assert a.keys() == b.keys() and any(k.startswith("average.") for k in a)
    assert all(torch.equal(a[k], b[k]) for k in a), "resumed run must end with the same weights"


def test_resume_refuses_a_different_config_but_allows_more_epochs(shared_data, tmp_path):
    from styleerd.train.trainer import train

    out = tmp_path / "r"
    train(TrainConfig(**TINY, epochs=1), out, progress=False)
    best = train(TrainConfig(**TINY, epochs=2), out, progress=False)
    assert epochs_done(out) == 2 and best["epoch"] >= 1
    with pytest.raises(StyleERDError, match="another config"):
        train(TrainConfig(**{**TINY, "lr_g": 1e-3}, epochs=3), out, progress=False)


@pytest.mark.parametrize(
    "ablation",
    [
        {"use_adv": False, "use_per": False},
        {"use_per": False},
        {"use_adv": False},
        {"attention": False},
        {"learned_init": False},
    ],
)
def test_ablation_switches_train(shared_data, tmp_path, ablation):
    from styleerd.train.trainer import train

    out = tmp_path / "ab"
    best = train(TrainConfig(**TINY, epochs=1, **ablation), out, progress=False)
    assert "rec_deg" in best and (out / "best.safetensors").is_file()
    assert (out / "content_classifier.safetensors").is_file() == ablation.get("use_per", True)


def test_cycle_and_content_losses_train_and_are_logged(shared_data, tmp_path):
    import csv

    from styleerd.train.trainer import train

    out = tmp_path / "cyc"
    train(TrainConfig(**TINY, epochs=1, w_cyc=1.0, w_cls=0.5), out, progress=False)
    with open(out / "metrics.csv", newline="") as f:
        row = next(csv.DictReader(f))
    assert 0.0 < float(row["loss_cyc"]) < 100.0  # transfer and back, compared with the input
    assert 0.0 < float(row["loss_cls"]) < 10.0  # cross-entropy over the contents of the tiny set
    # the lazy cycle (every 3rd step, weighted by 3) logs the mean over the steps that ran it
    lazy = tmp_path / "lazy"
    train(TrainConfig(**TINY, epochs=1, w_cyc=1.0, w_cls=0.5, cyc_every=3), lazy, progress=False)
    with open(lazy / "metrics.csv", newline="") as f:
        lazy_row = next(csv.DictReader(f))
    assert 0.5 < float(lazy_row["loss_cyc"]) / float(row["loss_cyc"]) < 2.0


def test_content_loss_ranks_the_true_content_first():
    import torch

    from styleerd.model.classifiers import WindowClassifier
    from styleerd.train import losses

    torch.manual_seed(0)
    clf = WindowClassifier(6, 3, channels=(8,), instance_norm=True)
    x = torch.randn(4, 12, 6)
    pred = clf(x).argmax(-1)
    maps = clf.feature_maps(x)
    right, wrong = (
        losses.content_classification(clf, maps, pred),
        losses.content_classification(clf, maps, (pred + 1) % 3),
    )
    assert right < wrong
    assert torch.isclose(right, torch.nn.functional.cross_entropy(clf(x), pred))


def test_data_parallel_two_processes_with_torchrun(shared_data, tmp_path):
    cfg = write_config(tmp_path / "c.yaml", epochs=2)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nproc_per_node",
            "2",
            "-m",
            "styleerd.cli",
            "train",
            "--config",
            str(cfg),
            "--out",
            str(tmp_path / "ddp"),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
        check=False,
    )
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    assert epochs_done(tmp_path / "ddp") == 2
    tensors, meta = ckpt.load_tensors(tmp_path / "ddp" / "checkpoint")
    assert meta["epoch"] == 2 and all(torch.isfinite(t).all() for t in tensors.values() if t.is_floating_point())


def test_recognisers_read_positions_and_velocities_and_report_the_ceiling(shared_data, tmp_path):
    from styleerd.data.features import FeatureLayout
    from styleerd.train.trainer import train_recognisers

    report = train_recognisers(TrainConfig(**TINY), out=tmp_path / "rec", progress=False)
    assert set(report) == {"style", "content"} and 0.0 <= report["style"]["test_accuracy"] <= 1.0
    style, _content, meta = ckpt.load_recognisers(tmp_path / "rec")
    layout = FeatureLayout(21)
    assert style.first_channel == layout.positions.start and style.in_dim == 6 * 21
    assert meta["content"]["labels"][0] == "raise-up-both-hands" and len(meta["style"]["labels"]) == 7
    x = torch.randn(3, 24, layout.dim)
    y = x.clone()
    y[..., layout.rotations] = 0  # rotations are not read
    assert torch.equal(style(x), style(y))


def test_both_bandai_sets_as_one_train_style_by_style(shared_data, tmp_path):
    """bandai-namco-1+2: Bandai-1's styles that Bandai-2 has under another name are renamed,
    its kept-back clips are the test split, its neutral actions held out of every training window, and a run
    with balanced styles trains."""
    import numpy as np

    from styleerd.data.cache import prepare
    from styleerd.data.datasets import bandai1_kept_back
    from styleerd.data.outside import BANDAI1_ACTIONS
    from styleerd.model.checkpoint import load_generator
    from styleerd.train.batches import training_clips, training_data, windows
    from styleerd.train.trainer import train

    fs = prepare("bandai-namco-1+2", shared_data, progress=False)
    styles = set(fs.styles.tolist())
    assert {"elderly", "exhausted", "masculine", "happy", "chimpira", "youthful"} <= styles and not {
        "old",
        "tired",
        "masculinity",
    } & styles
    assert len(styles) == 16  # Bandai-1's 15 (three renamed) and Bandai-2's youthful
    one = np.char.startswith(fs.names.astype(str), "dataset-1_")
    held = np.array([bandai1_kept_back(n, c) for n, c in zip(fs.names, fs.contents)])
    assert (fs.splits[one & held] == "test").all() and (fs.splits[one & ~held] == "train").all()
    assert ((fs.styles == "happy") & one & held).sum() == 5 and ((fs.styles == "happy") & one & ~held).sum() == 6
    assert set(fs.splits[~one]) == {"train", "val", "test"}  # Bandai-2 keeps its split by take
    # Bandai-1's neutral actions (`styleerd eval actions` reports on them) are in no training window
    actions = one & (fs.styles == "normal") & np.isin(fs.contents, BANDAI1_ACTIONS) & ~held
    trained = training_clips(fs)
    assert actions.sum() >= 7 and not set(np.nonzero(actions)[0]) & set(trained.tolist())
    assert set(trained.tolist()) == set(fs.clips("train").tolist()) - set(np.nonzero(actions)[0])
    starts = windows(fs, training_data(fs, 24), "train", 20).starts
    assert not np.isin(np.searchsorted(fs.clip_start, starts, side="right") - 1, np.nonzero(actions)[0]).any()
    assert "kick" in training_data(fs, 24).contents  # the content stays: the labeller and recognisers name it
    out = tmp_path / "b12"
    train(
        TrainConfig(
            **{**TINY, "max_train_clips": 0}, dataset="bandai-namco-1+2", balance_styles=True, epochs=1, stride=200
        ),
        out,
        progress=False,
        export=tmp_path / "m",
    )
    model, _ = load_generator(tmp_path / "m")
    assert model.config.styles == tuple(sorted(styles)) and "bow" in model.config.contents


def test_fine_tune_from_a_saved_generator_with_a_critic_that_sees_rotations(shared_data, tmp_path, monkeypatch):
    from styleerd.train.trainer import train

    train(TrainConfig(**TINY, epochs=1), tmp_path / "a", progress=False, export=tmp_path / "start")
    start, _ = ckpt.load_generator(tmp_path / "start")
    # lr_g 0: the fine-tuned generator must be exactly the one it started from
    tuning = TrainConfig(
        **{**TINY, "lr_g": 0.0}, epochs=1, init_from=str(tmp_path / "start"), critic_rotations=True, keep="last"
    )
    train(tuning, tmp_path / "b", progress=False, export=tmp_path / "tuned")
    tensors, _ = ckpt.load_tensors(tmp_path / "b" / "checkpoint")
    tuned = ckpt.unprefixed("generator", tensors)
    assert all(torch.equal(v, tuned[k]) for k, v in start.state_dict().items())
    exported, meta = ckpt.load_generator(tmp_path / "tuned")  # keep "last": the final epoch, with where it started
    assert all(torch.equal(v, exported.state_dict()[k]) for k, v in start.state_dict().items())
    assert "last epoch" in meta["training"]["kept"] and meta["training"]["started_from"]["model"] == str(
        tmp_path / "start"
    )
    assert meta["training"]["started_from"]["training"]["epochs_trained"] == 1
    # where a run started and what it exports may change on resuming (the checkpoint holds the weights)
    train(
        TrainConfig(**{**tuning.to_dict(), "epochs": 2, "keep": "best", "init_from": ""}),
        tmp_path / "b",
        progress=False,
    )
    # ema: the export (and every validation) is the moving average of the weights, not the weights
    train(
        TrainConfig(**TINY, epochs=1, init_from=str(tmp_path / "start"), keep="last", ema=0.99),
        tmp_path / "m",
        progress=False,
        export=tmp_path / "averaged",
    )
    tensors_m, _ = ckpt.load_tensors(tmp_path / "m" / "checkpoint")
    averaged, meta = ckpt.load_generator(tmp_path / "averaged")
    assert "moving average (decay 0.99)" in meta["training"]["kept"]
    average, raw = ckpt.unprefixed("average", tensors_m), ckpt.unprefixed("generator", tensors_m)
    assert all(torch.equal(v, average[k]) for k, v in averaged.state_dict().items())
    assert not all(torch.equal(v, raw[k]) for k, v in averaged.state_dict().items())
    with pytest.raises(StyleERDError, match="ema must be a decay"):
        train(TrainConfig(**TINY, epochs=1, ema=1.0), tmp_path / "f", progress=False)
    with pytest.raises(StyleERDError, match="keep must be"):
        train(TrainConfig(**{**TINY, "keep": "newest"}, epochs=1), tmp_path / "d", progress=False)
    # keep "realistic": every validation epoch judged by realism per style; the export is the most realistic one
    train(
        TrainConfig(**TINY, epochs=3, init_from=str(tmp_path / "start"), keep="realistic"),
        tmp_path / "r",
        progress=False,
        export=tmp_path / "realistic",
    )
    rows = list(csv.DictReader((tmp_path / "r" / "metrics.csv").read_text().splitlines()))
    margins = [float(r["realism_margin"]) for r in rows]
    assert len(margins) == 3 and all(0 < m < 10 for m in margins)
    assert all(float(r["worst_fmd_over_floor"]) > 0 and 0 < float(r["worst_cra_of_ceiling"]) <= 1.5 for r in rows)
    realistic, meta = ckpt.load_generator(tmp_path / "realistic")
    chosen = max(range(3), key=lambda i: margins[i]) + 1
    assert meta["training"]["best"]["epoch"] == chosen and f"epoch {chosen} of 3" in meta["training"]["kept"]
    best, _ = ckpt.load_generator(tmp_path / "r" / "best")
    assert all(torch.equal(v, best.state_dict()[k]) for k, v in realistic.state_dict().items())
    monkeypatch.setattr(
        "styleerd.train.trainer._recognisers", lambda s: (None, None)
    )  # judges that do not fit the data
    with pytest.raises(StyleERDError, match="keep: realistic needs the shipped recognisers"):
        train(TrainConfig(**TINY, epochs=1, keep="realistic"), tmp_path / "e", progress=False)
    J = start.config.n_joints
    assert tensors["discriminator.trunk.0.1.weight"].shape[1] == 10 * J  # rotations, positions, velocities
    plain, _ = ckpt.load_tensors(tmp_path / "a" / "checkpoint")
    assert plain["discriminator.trunk.0.1.weight"].shape[1] == 6 * J  # the paper's critic: positions, velocities
    with pytest.raises(StyleERDError, match="init_from .* config differs"):
        train(
            TrainConfig(**{**TINY, "neutral_layers": 3}, epochs=1, init_from=str(tmp_path / "start")),
            tmp_path / "c",
            progress=False,
        )
    # pose_change from a model without it: the run starts from "no change", every pose the input's own
    train(
        TrainConfig(**{**TINY, "lr_g": 0.0}, epochs=1, init_from=str(tmp_path / "start"), pose_change=True),
        tmp_path / "p",
        progress=False,
        export=tmp_path / "change",
    )
    change, _ = ckpt.load_generator(tmp_path / "change")
    assert change.config.pose_change and not start.config.pose_change
    x = torch.randn(3, 8, change.config.feature_dim)
    style = torch.eye(len(change.config.styles))[[0, 1, 2]]
    content = torch.eye(len(change.config.contents))[[0, 3, 4]]
    rot, _, _ = change(x, style, content, torch.eye(len(change.config.styles))[[4, 1, 6]])
    assert torch_quat.angle(rot, change.raw_rotations(x)).max() < 1e-3  # radians
    rot_start, _, _ = start(x, style, content, torch.eye(len(change.config.styles))[[4, 1, 6]])
    assert torch_quat.angle(rot_start, start.raw_rotations(x)).max() > 0.5  # the pose network rebuilds it
    with pytest.raises(StyleERDError, match="init_from .* config differs"):  # not back from a change network
        train(TrainConfig(**TINY, epochs=1, init_from=str(tmp_path / "change")), tmp_path / "q", progress=False)
    # a run that resumes takes its weights from its checkpoint: the model it started from may be gone
    for suffix in (".safetensors", ".json"):
        (tmp_path / "start").with_suffix(suffix).unlink()
    train(
        TrainConfig(**TINY, epochs=2, init_from=str(tmp_path / "start"), keep="last", ema=0.99),
        tmp_path / "m",
        progress=False,
    )
    assert len(list(csv.DictReader((tmp_path / "m" / "metrics.csv").read_text().splitlines()))) == 2
    with pytest.raises(StyleERDError, match="device 'no-such-device' cannot be used"):
        train(TrainConfig(**TINY, epochs=1, device="no-such-device"), tmp_path / "g", progress=False)


def test_moving_average_of_the_weights_follows_its_formula():
    from conftest import walking_motion

    from styleerd.data.features import FeatureStats, motion_features
    from styleerd.model.generator import GeneratorConfig, StyleERD
    from styleerd.train.trainer import update_average

    m = walking_motion(30)
    stats = FeatureStats.fit(motion_features(m)[0], m.skeleton.n_joints)
    config = GeneratorConfig(m.skeleton.n_joints, ("normal", "old"), ("walk",), neutral_layers=2, style_layers=1)
    torch.manual_seed(0)
    G, G_avg = StyleERD(config, m.skeleton, stats), StyleERD(config, m.skeleton, stats)
    before = {k: v.clone() for k, v in G_avg.state_dict().items()}
    update_average(G_avg, G, 0.75)
    for k, v in G_avg.state_dict().items():
        torch.testing.assert_close(v, 0.75 * before[k] + 0.25 * G.state_dict()[k])


def test_realism_margin_is_the_worst_styles_distance_inside_both_bars():
    from styleerd.train.validation import realism_margin

    q = {
        "fmd_per_style": {"a": 0.03, "b": 0.02},
        "fmd_floor_per_style": {"a": 0.02, "b": 0.02},
        "cra_per_style": {"a": 0.9, "b": 0.95},
        "content_ceiling_per_style": {"a": 1.0, "b": 0.95},
    }
    m = realism_margin(q)  # a: FMD 1.5 x (margin 2), CRA 90 % (margin 0.947); b: FMD 1 x, CRA 100 %
    assert m == {"worst_fmd_over_floor": 1.5, "worst_cra_of_ceiling": 0.9, "realism_margin": round(0.9 / 0.95, 4)}
    q["fmd_per_style"]["b"] = 0.08  # 4 x its floor: the worst margin is now b's FMD, 3 / 4
    assert realism_margin(q)["realism_margin"] == 0.75


def test_a_train_step_moves_both_networks_and_leaves_them_trainable(shared_data):
    """The generator's step reads the critic with its weights frozen (it needs the gradient to
    its input only); the critic's own step must find them trainable again."""
    import numpy as np

    from styleerd.model.classifiers import WindowClassifier
    from styleerd.train.trainer import make_critic, make_generator, make_optimisers, setup, train_step

    config = TrainConfig(**TINY, critic_rotations=True, w_cls=0.3, w_cyc=1.0)
    s = setup(config, shared_data, progress=False)
    G, D = make_generator(config, s), make_critic(config, s)
    C = WindowClassifier(10 * G.config.n_joints, len(s.data.contents), instance_norm=True).requires_grad_(False)
    before = [p.detach().clone() for p in (*G.parameters(), *D.parameters())]
    rng = np.random.default_rng(0)
    logs = {}
    for step in range(2):  # R1 on the first
        logs |= train_step(
            G,
            D,
            *make_optimisers(config, G, D),
            C,
            config,
            s,
            rng.choice(len(s.train.starts), 16),
            rng.integers(0, len(s.data.styles), 16),
            step,
        )
    assert {"rec", "adv", "per", "cls", "cyc", "critic", "r1"} <= logs.keys() and all(
        np.isfinite(v) for v in logs.values()
    )
    assert all(p.requires_grad for p in D.parameters()) and all(p.requires_grad for p in G.parameters())
    moved = [not torch.equal(a, p) for a, p in zip(before, (*G.parameters(), *D.parameters()))]
    assert all(moved[len(list(G.parameters())) :]), "every critic weight must train"
    assert sum(moved[: len(list(G.parameters()))]) > 0.9 * len(list(G.parameters()))


def test_bench_train_step_times_the_trainers_own_step_of_two_recipes(shared_data, tmp_path):
    import json

    before = write_config(tmp_path / "before.yaml", w_cyc=1.0, w_cls=0.3, w_per=0.5)
    after = write_config(tmp_path / "after.yaml", critic_rotations=True, batch_size=12)  # its own batch
    out = tmp_path / "step.json"
    bench = subprocess.run(
        [
            sys.executable,
            "benchmarks/bench_train_step.py",
            "--steps",
            "4",
            "--threads",
            "1",
            "--before",
            before,
            "--before-code",
            "HEAD",
            "--after",
            after,
            "--json",
            out,
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=os.path.dirname(os.path.dirname(__file__)),
        check=False,
    )
    assert bench.returncode == 0, bench.stderr
    r = json.loads(out.read_text())
    assert "cycle pass + loss" in r["before"]["parts_ms"] and "cycle pass + loss" not in r["after"]["parts_ms"]
    assert r["before"]["batch"] == 16 and r["after"]["batch"] == 12
    assert (
        r["before"]["code"] == "HEAD" and r["after"]["code"] == "working tree"
    )  # the before recipe on the committed trainer, from git
    for name in ("before", "after"):
        parts = r[name]["parts_ms"]
        assert {
            "generator forward (B + B)",
            "generator backward + Adam",
            "critic step (+ R1 on its steps)",
        } <= parts.keys()
        assert all(v > 0 for v in parts.values()) and abs(sum(parts.values()) - r[name]["step_ms"]) < 0.1
    # the ratio of the epoch times as printed (each rounded to 0.0005 s), within what that rounding and
    # the speedup's own (0.0005) allow: a fixed 0.002 failed on 0.509 / 0.508 against 1.004
    b, a = r["before"]["epoch_s"], r["after"]["epoch_s"]
    assert abs(r["speedup"] - b / a) <= 0.0005 / a + 0.0005 * b / a**2 + 0.0005 + 1e-9
    assert "after / before epoch time" in bench.stdout


def test_bench_train_parallel_times_real_epochs_in_one_and_two_processes(shared_data, tmp_path):
    import json

    cfg = write_config(tmp_path / "c.yaml")
    out = tmp_path / "parallel.json"
    bench = subprocess.run(
        [
            sys.executable,
            "benchmarks/bench_train_parallel.py",
            "--config",
            cfg,
            "--clips",
            "40",
            "--rounds",
            "1",
            "--data",
            shared_data,
            "--json",
            out,
        ],
        capture_output=True,
        text=True,
        timeout=900,
        cwd=os.path.dirname(os.path.dirname(__file__)),
        check=False,
    )
    assert bench.returncode == 0, bench.stdout[-2000:] + bench.stderr[:3000] + "\n...\n" + bench.stderr[-3000:]
    r = json.loads(out.read_text())
    forms = r["forms"]
    assert list(forms) == ["1 process x 1 thread", "1 process x 2 threads", "2 processes x 1 thread (torchrun)"]
    assert (
        len({f["steps"] for f in forms.values()}) == 1 and forms["1 process x 1 thread"]["speedup"] == 1.0
    )  # one global batch: the same steps
    for f in forms.values():
        assert f["epoch_s"] > 0 and abs(f["windows_per_minute"] - 60 * f["steps"] * 16 / f["epoch_s"]) <= 1


def test_training_with_a_data_folder_given_needs_no_default_one(shared_data, tmp_path, monkeypatch):
    """--data DIR is enough: nothing falls back to ../shared/data (absent on other machines)."""
    from styleerd.data import datasets
    from styleerd.train.trainer import train

    monkeypatch.delenv("STYLEERD_DATA", raising=False)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(datasets, "__file__", str(tmp_path / "a" / "b" / "datasets.py"))
    with pytest.raises(StyleERDError, match="data directory .* not found"):
        datasets.data_root(None)
    train(TrainConfig(**TINY, epochs=1), tmp_path / "run", str(shared_data), progress=False, export=tmp_path / "m")
    _, meta = ckpt.load_generator(tmp_path / "m")
    assert meta["data"]["sha256"] == datasets.file_digest(shared_data / "bandai-namco-2.tar.xz")


def test_other_performers_windows_are_rebuilt_in_their_own_style_whatever_content_they_are_told(shared_data):
    """``outside_batch``: windows of Bandai-Namco-1's and cmu-sample's clips (none held out, every one
    in a style the model has) join each step as a reconstruction told a random content; a fixed batch of
    them, trained on alone, is rebuilt better and better."""
    import numpy as np

    from styleerd.data.augment import STRAIGHT, TRAVELLING
    from styleerd.data.features import FeatureLayout
    from styleerd.train.batches import in_place_clips, outside_contents, outside_windows
    from styleerd.train.trainer import make_critic, make_generator, make_optimisers, setup, train_step

    config = TrainConfig(**TINY, use_adv=False, use_per=False, w_rec=0.0, outside_batch=16)
    s = setup(config, shared_data, progress=False)
    s.outside = outside_windows(s.fs, s.data, config.stride, shared_data, progress=False)
    o = s.outside
    assert len(o.starts) > 500 and (o.style >= 0).all() and o.starts.max() + config.window <= len(o.frames)
    assert set(np.unique(o.style)) >= {s.data.styles.index(k) for k in ("normal", "elderly", "active")}
    assert o.gather(np.arange(len(o.starts)), config.window).abs().max() <= 16.0  # beyond the training data's range
    assert s.data.gather(s.train.starts).abs().max() <= 16.0
    # and walks of the training split in place: their rotations as they were, the root's ground speed 0
    frames, starts, style, content = in_place_clips(s.fs, s.data)
    c = next(c for c in s.fs.clips("train") if s.fs.contents[c] in TRAVELLING)
    assert content[0] == s.data.contents.index(s.fs.contents[c])
    first = frames[starts[0] : starts[1]].numpy()
    L = FeatureLayout(s.fs.skeleton.n_joints)
    mean, std = s.data.stats.mean, s.data.stats.std
    root_velocity = first[:, L.velocities][:, [0, 2]] * std[L.velocities][[0, 2]] + mean[L.velocities][[0, 2]]
    assert np.abs(root_velocity).max() < 1e-4 and style[0] == s.data.styles.index(s.fs.styles[c])
    given = s.data.frames[s.fs.frames(c)].numpy()
    assert np.abs(first[:, L.rotations] - given[:, L.rotations]).max() < 1e-3
    # outside_neutral: other performers' clips in the neutral style only (the walks in place come last)
    n = s.data.styles.index("normal")
    only = outside_windows(s.fs, s.data, config.stride, shared_data, progress=False, neutral=n)
    performers = only.starts < len(only.frames) - len(frames)
    assert (only.style[performers] == n).all() and 0 < performers.sum() < (o.starts < len(o.frames) - len(frames)).sum()
    # outside_in_place false: other performers' clips alone, the same windows of them
    others = outside_windows(s.fs, s.data, config.stride, shared_data, progress=False, in_place=False)
    assert len(others.frames) == len(o.frames) - len(frames) and others.starts.max() + config.window <= len(
        others.frames
    )
    assert np.array_equal(others.starts, o.starts[o.starts < len(others.frames)])
    # each window's content: the in-place walks' own, other performers' where the model has it, else -1
    placed = o.starts >= len(others.frames)
    assert set(np.unique(o.content[placed])) <= {s.data.contents.index(k) for k in TRAVELLING if k in s.data.contents}
    assert (o.content[placed] >= 0).all() and (o.content[~placed] == -1).any() and (o.content[~placed] >= 0).any()
    # outside_turns_in_place false: straight walks and runs alone in place
    straight = outside_windows(s.fs, s.data, config.stride, shared_data, progress=False, turns_in_place=False)
    placed_straight = straight.starts >= len(others.frames)
    assert placed_straight.sum() > 0 and set(np.unique(straight.content[placed_straight])) <= {
        s.data.contents.index(k) for k in STRAIGHT
    }
    assert np.array_equal(straight.starts[~placed_straight], others.starts)
    # what they are told: a random content, or with outside_known_content their own where known
    told = outside_contents(o.content[:: len(o.starts) // 200], len(s.data.contents), False, np.random.default_rng(1))
    assert np.allclose(told.sum(1), 1.0) and (told.max(1) < 1.0).all()
    known = outside_contents(o.content[:: len(o.starts) // 200], len(s.data.contents), True, np.random.default_rng(1))
    mine = o.content[:: len(o.starts) // 200] >= 0
    assert np.array_equal(known[mine].argmax(1), o.content[:: len(o.starts) // 200][mine])
    assert (known[mine].max(1) == 1.0).all() and np.array_equal(known[~mine], told[~mine])
    torch.manual_seed(0)
    G, D = make_generator(config, s), make_critic(config, s)
    opt_g, opt_d = make_optimisers(config, G, D)
    rng = np.random.default_rng(0)
    rows, target = rng.choice(len(s.train.starts), 16), rng.integers(0, len(s.data.styles), 16)
    batch = rng.choice(len(o.starts), 16)
    losses = []
    for step in range(40):  # a new random content each step: the loss falls all the same
        content = rng.dirichlet(np.full(len(s.data.contents), 0.3), 16)
        logs = train_step(G, D, opt_g, opt_d, None, config, s, rows, target, step, outside=(batch, content))
        losses.append(logs["outside"])
    assert np.isfinite(losses).all() and np.mean(losses[-5:]) < 0.6 * np.mean(losses[:5]), losses


def test_keep_holds_a_fine_tunes_transfers_near_the_model_it_started_from(shared_data, tmp_path):
    """``w_keep``: the training windows' transfers are pulled towards the frozen start model's, so
    after the same steps they are nearer to it than without; the run needs a model to start from."""
    import copy

    import numpy as np

    from styleerd.train.trainer import make_critic, make_generator, make_optimisers, setup, train, train_step

    config = TrainConfig(**TINY, lr_g=1e-3, use_per=False)
    s = setup(config, shared_data, progress=False)
    torch.manual_seed(0)
    start = make_generator(config, s).requires_grad_(False)
    rng = np.random.default_rng(0)
    rows, target = rng.choice(len(s.train.starts), 16), rng.integers(0, len(s.data.styles), 16)
    x = s.data.gather(s.train.starts[rows])
    style, content = s.data.onehot_style(s.train.style[rows]), s.data.onehot_content(s.train.content[rows])
    tgt = s.data.onehot_style(target)

    def drift(w_keep: float) -> tuple[float, list[float]]:
        torch.manual_seed(1)
        G, D = copy.deepcopy(start).requires_grad_(True), make_critic(config, s)
        opt_g, opt_d = make_optimisers(config, G, D)
        kept = TrainConfig.from_dict({**config.to_dict(), "w_keep": w_keep})
        logs = [
            train_step(G, D, opt_g, opt_d, None, kept, s, rows, target, step, start=start if w_keep else None)
            for step in range(12)
        ]
        with torch.no_grad():
            rot, _ = G.forward_targets(x, style, content, tgt)
            rot_start, _ = start.forward_targets(x, style, content, tgt)
        return torch_quat.angle(rot, rot_start).mean().item(), [log.get("keep", 0.0) for log in logs]

    free, _ = drift(0.0)
    held, keep = drift(20.0)
    assert keep[0] < 1e-4 and keep[1] > 1e-2, keep  # the same weights at the first step, then apart
    assert held < 0.5 * free, (held, free)
    with pytest.raises(StyleERDError, match="w_keep .* needs init_from"):
        train(TrainConfig(**TINY, epochs=1, w_keep=1.0), tmp_path / "k", progress=False)
    # through the trainer: the loss is logged per epoch, and a resumed run keeps to the model it started from
    train(TrainConfig(**TINY, epochs=1), tmp_path / "a", progress=False, export=tmp_path / "start")
    tuning = TrainConfig(**TINY, epochs=1, init_from=str(tmp_path / "start"), w_keep=1.0)
    train(tuning, tmp_path / "b", progress=False)
    train(TrainConfig.from_dict({**tuning.to_dict(), "epochs": 2}), tmp_path / "b", progress=False)
    rows = list(csv.DictReader((tmp_path / "b" / "metrics.csv").read_text().splitlines()))
    assert len(rows) == 2 and all(0.0 < float(r["loss_keep"]) < 1.0 for r in rows), rows
    # the reference is the start model as saved, even where the run's own decoder starts elsewhere (pose_change)
    from styleerd.train.trainer import _frozen_start

    saved, _ = ckpt.load_generator(tmp_path / "start")
    changing = TrainConfig(**TINY, init_from=str(tmp_path / "start"), w_keep=1.0, pose_change=True)
    reference = _frozen_start(changing, make_generator(changing, s))
    assert not reference.config.pose_change and not any(p.requires_grad for p in reference.parameters())
    assert all(torch.equal(v, reference.state_dict()[k]) for k, v in saved.state_dict().items())
