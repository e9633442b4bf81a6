"""The online labeller on other performers' clips (`styleerd eval labels`), and its training with
them: the clips it is measured on are never trained on, and the unsure loss of a style the model
does not have is smallest where the posterior is uniform."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from styleerd.data.datasets import bandai1_kept_back
from styleerd.data.outside import held_out
from styleerd.train.labeller import labeller_loss


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
