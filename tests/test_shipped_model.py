"""The shipped model and recognisers: self-contained, small, and as good as the issue asks."""

import json

import pytest
import torch

from styleerd.model import checkpoint as ckpt
from styleerd.models import DEFAULT_MODEL, MODELS_DIR

SHIPPED = MODELS_DIR / DEFAULT_MODEL
# Fractions of the recognisers' accuracy on real test windows that issue 3 asks for (the
# shipped model measures 0.9945 and 0.9878).
SRA_TARGET = 0.80
CRA_TARGET = 0.95


def training_runs(training: dict):
    """Every training run behind a model's ``training`` record: a soup's stages, and what each run
    started from."""
    if "soup" in training:
        for stage in training["soup"]:
            yield from training_runs(stage["training"])
        return
    yield training
    if "started_from" in training:
        yield from training_runs(training["started_from"]["training"])


def test_shipped_model_is_self_contained_and_small():
    model, meta = ckpt.load_generator()
    assert set(model.config.styles) == {"active", "elderly", "exhausted", "feminine", "masculine", "normal", "youthful"}
    assert len(model.config.contents) == 10 and model.config.neutral_style == "normal"
    for key in ("config", "skeleton", "stats", "code_version", "data", "training"):
        assert key in meta
    assert len(meta["data"]["sha256"]) == 64
    # each training run of the recipe fits in 90 minutes (issue 3): the shipped model is a chain of
    # runs, each fine-tuning the one before, and soups (weight averages) of runs from the same start
    runs = list(training_runs(meta["training"]))
    assert len(runs) >= 3 and all(t["wall_minutes"] <= 90 for t in runs), [t["wall_minutes"] for t in runs]
    assert SHIPPED.with_suffix(".safetensors").stat().st_size < 5 * 2**20
    assert json.loads(SHIPPED.with_suffix(".json").read_text()) == meta  # the readable sidecar says the same
    x = torch.zeros(1, 3, model.config.feature_dim)
    s = torch.eye(7)[[5]]
    rot, _vel, _ = model(x, s, torch.eye(10)[[0]], s)
    assert torch.isfinite(rot).all() and rot.shape == (1, 3, 21, 4)


@pytest.mark.slow
def test_shipped_model_meets_the_recognition_targets_on_the_test_split(shared_data):
    from styleerd.train.trainer import evaluate

    r = evaluate(data_dir=str(shared_data), progress=False)
    print(r)
    assert r["windows"] > 1000
    assert r["sra_of_ceiling"] >= SRA_TARGET and r["cra_of_ceiling"] >= CRA_TARGET
    per = r["per_target"]  # the per-style breakdown adds up to the whole
    n = sum(v["transfers"] for v in per.values())
    assert set(per) == set(ckpt.load_generator()[0].config.styles)
    assert abs(sum(v["sra"] * v["transfers"] for v in per.values()) / n - r["sra"]) < 1e-3


@pytest.mark.slow
def test_shipped_labeller_labels_test_streams_as_its_record_says(shared_data):
    from styleerd.train.config import TrainConfig
    from styleerd.train.labeller import stream_accuracy
    from styleerd.train.trainer import setup

    labeller, meta = ckpt.load_labeller()
    s = setup(TrainConfig(), str(shared_data), progress=False)
    acc = stream_accuracy(labeller, s.fs, s.data, "test")
    print(acc)
    assert {str(k): v for k, v in acc.items()} == meta["test"]  # the recorded figures are reproducible
    assert acc[1]["style"] >= 0.85 and acc[30]["style"] >= 0.97 and acc[30]["content"] >= 0.9


def test_the_16_style_model_transfers_into_its_bandai1_styles_with_labels_inferred(tmp_path):
    """styleerd-bandai12 (configs/bandai12-outside.yaml): its labels are inferred by its own labeller
    (found by its labels), and it works from the command line like the default model."""
    import subprocess
    import sys

    from styleerd.model.stored import labeller_stem, load_generator_weights
    from styleerd.motion import bvh, procedural

    w = load_generator_weights("styleerd-bandai12")
    assert len(w.config.styles) == 16 and {"happy", "chimpira", "elderly", "youthful"} <= set(w.config.styles)
    assert labeller_stem(w.config).name == "labeller-bandai12"
    bvh.write(tmp_path / "walk.bvh", procedural.walk(seconds=2.0, fps=30.0))
    for argv in (
        ["transfer", "walk.bvh", "--style", "happy", "-o", "out.bvh"],
        ["export-onnx", "--styles", "happy,sad", "-o", "step.onnx"],
    ):
        done = subprocess.run(
            [sys.executable, "-m", "styleerd.cli", *argv, "--model", "styleerd-bandai12"],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        assert done.returncode == 0, done.stderr
    assert bvh.read(tmp_path / "out.bvh").n_frames == 60
    assert json.loads((tmp_path / "step.json").read_text())["branch_styles"] == ["happy", "sad"]


@pytest.mark.slow
def test_shipped_model_is_realistic_in_every_style_with_the_content_kept(shared_data):
    """Issue 16: every target style's FMD within 3 x its floor (two halves of the style's real
    test windows) and CRA >= 95 % of the content recogniser's ceiling, both at once (the
    shipped model measures FMD <= 1.68 x and CRA >= 95.4 %, normal the lowest)."""
    from styleerd.eval.metrics import evaluate_model
    from styleerd.eval.recipes import per_style
    from styleerd.train.validation import CRA_BAR, FMD_BAR

    q = evaluate_model(ckpt.load_generator()[0], str(shared_data))
    ratios = per_style(q)
    print(ratios)
    assert set(ratios) == set(ckpt.load_generator()[0].config.styles)
    for style, r in ratios.items():
        assert r["fmd_over_floor"] <= FMD_BAR and r["cra_of_ceiling"] >= CRA_BAR, (style, r)
