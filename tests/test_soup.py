"""styleerd soup: the weighted average of the weights of generators fine-tuned from one start."""

import copy

import pytest
import torch

from styleerd import cli
from styleerd.errors import StyleERDError
from styleerd.model import checkpoint as ckpt
from styleerd.train.soup import soup


@pytest.fixture
def two_stages(tmp_path):
    """The shipped model and a copy of it with other weights, both fine-tuned from the same start."""
    model, meta = ckpt.load_generator()
    other = copy.deepcopy(model)
    with torch.no_grad():
        for p in other.parameters():
            p.add_(torch.randn_like(p) * 0.01)
    ckpt.save_tensors(tmp_path / "a", ckpt.prefixed("generator", model), meta)
    ckpt.save_tensors(tmp_path / "b", ckpt.prefixed("generator", other), meta)
    return tmp_path / "a", tmp_path / "b", model, other, meta


def test_soup_is_the_weighted_average_of_the_weights(two_stages, tmp_path, capsys):
    a, b, model, other, meta = two_stages
    assert cli.main(["soup", str(a), str(b), "--weights", "0.25", "0.75", "-o", str(tmp_path / "s")]) in (0, None)
    said = capsys.readouterr().out
    assert f"styleerd posture {tmp_path / 's'}" in said and f"styleerd familiar {tmp_path / 's'}" in said
    averaged, m = ckpt.load_generator(tmp_path / "s")
    sa, sb, ss = model.state_dict(), other.state_dict(), averaged.state_dict()
    for k in sa:
        assert torch.allclose(ss[k], 0.25 * sa[k] + 0.75 * sb[k], atol=1e-7), k
    for k in ("mean", "std", "offsets", "reference"):  # what both share comes back bit for bit
        assert torch.equal(ss[k], sa[k])
    assert [s["weight"] for s in m["training"]["soup"]] == [0.25, 0.75] and m["training"]["started_from"] == meta[
        "training"
    ]["started_from"]
    assert m["training"]["wall_minutes"] == pytest.approx(2 * meta["training"]["wall_minutes"], abs=0.01)
    x = torch.zeros(1, 3, averaged.config.feature_dim)
    rot, _, _ = averaged(x, torch.eye(7)[[5]], torch.eye(10)[[0]], torch.eye(7)[[1]])
    assert torch.isfinite(rot).all()
    _, equal = soup([str(a), str(b)])
    assert [s["weight"] for s in equal["training"]["soup"]] == [0.5, 0.5]
    # the shipped model's measured familiar range is its own, not the average's: the soup has the default
    assert "familiar" in meta and "familiar" not in m and averaged.familiar == (10.0, 16.0)
    # its posture is the first model's, and says so
    assert m["posture"]["offsets"] == meta["posture"]["offsets"]
    assert m["posture"]["measured_on"].startswith(f"{a}'s (the soup's first model): {meta['posture']['measured_on']}")


def test_soup_refuses_what_does_not_average_into_a_model(two_stages, tmp_path):
    a, b, model, other, meta = two_stages
    with pytest.raises(StyleERDError, match="at least two"):
        soup([str(a)])
    with pytest.raises(StyleERDError, match="summing to 1"):
        soup([str(a), str(b)], [0.7, 0.7])
    with pytest.raises(StyleERDError, match="one per model"):
        soup([str(a), str(b)], [1.0])
    elsewhere = {**meta, "training": {**meta["training"], "started_from": {"model": "models/other", "training": {}}}}
    ckpt.save_tensors(tmp_path / "c", ckpt.prefixed("generator", other), elsewhere)
    with pytest.raises(StyleERDError, match="was not fine-tuned from"):
        soup([str(a), str(tmp_path / "c")])
    with pytest.raises(StyleERDError, match="differs from"):
        soup([str(a), "styleerd-bandai12"])
    scratch = {**meta, "training": {k: v for k, v in meta["training"].items() if k != "started_from"}}
    ckpt.save_tensors(tmp_path / "d", ckpt.prefixed("generator", model), scratch)
    with pytest.raises(StyleERDError, match="not fine-tuned from a saved model"):
        soup([str(tmp_path / "d"), str(a)])
    assert cli.main(["soup", str(a), str(tmp_path / "c"), "-o", str(tmp_path / "bad")]) not in (0, None)
    assert not list(tmp_path.glob("bad*"))  # nothing written


def test_the_report_names_every_stage_of_a_soup(two_stages):
    from styleerd.eval.report import training_minutes

    a, b, _, _, meta = two_stages
    _, m = soup([str(a), str(b)])
    text = training_minutes(m["training"])
    stage = f"{meta['training']['wall_minutes']} min ({meta['training']['config']['name']})"
    assert text.count(stage) == 2 and "each fine-tuning from it, their weights averaged" in text
    assert text.startswith(training_minutes(meta["training"]["started_from"]["training"]) + " + ")
    # a fine-tune of the soup names the soup's stages, then its own
    tuned = training_minutes(
        {"config": {"name": "t"}, "wall_minutes": 3.5, "started_from": {"training": m["training"]}}
    )
    assert tuned == f"{text}; then 3.5 min (t), fine-tuning from it"


def test_the_wise_sweep_mixes_a_fine_tune_with_its_start():
    """benchmarks/wise_sweep.py: share 0 is the start's weights, 1 the fine-tune's, between their
    weighted mean; a model not fine-tuned from the start is refused."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from wise_sweep import ROOT, mixed

    tuned = str(ROOT / "models" / "recipes" / "bandai2-outside")
    start, tuned_model = ckpt.load_generator()[0].state_dict(), ckpt.load_generator(tuned)[0].state_dict()
    for share in (0.0, 0.3, 1.0):
        tensors, meta = mixed("styleerd-bandai2", tuned, share)
        for k in start:
            want = (1 - share) * start[k].double() + share * tuned_model[k].double()
            assert torch.allclose(tensors[f"generator.{k}"].double(), want, atol=1e-6), (share, k)
        assert "posture" not in meta and meta["training"]["config"]["name"].endswith(f"{share:g} bandai2-outside")
    with pytest.raises(SystemExit, match="not fine-tuned from"):
        mixed("styleerd-bandai12", tuned, 0.5)
