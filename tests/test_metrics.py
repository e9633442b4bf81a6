"""The evaluation metrics: the Fréchet distance against scipy's matrix square root, the
shipped FMD extractor against its record, the quality and runtime figures of the shipped
models on the test split."""

import numpy as np
import pytest
import scipy.linalg

from styleerd.eval.metrics import runtime_report
from styleerd.model import checkpoint as ckpt
from styleerd.model.checkpoint import load_generator, load_labeller
from styleerd.train.validation import frechet_distance, misread


def test_frechet_distance_against_scipy_sqrtm():
    rng = np.random.default_rng(0)
    a = rng.normal(0, 1, (400, 6)) @ rng.normal(0, 1, (6, 6))
    b = rng.normal(0.3, 1.5, (300, 6)) @ rng.normal(0, 1, (6, 6))
    ca, cb = np.cov(a, rowvar=False), np.cov(b, rowvar=False)
    expected = np.sum((a.mean(0) - b.mean(0)) ** 2) + np.trace(ca + cb - 2 * scipy.linalg.sqrtm(ca @ cb).real)
    assert np.isclose(frechet_distance(a, b), expected, rtol=1e-6)
    assert abs(frechet_distance(a, a)) < 1e-8


@pytest.mark.slow
def test_shipped_fmd_extractor_and_the_quality_figures(shared_data):
    from styleerd.eval.metrics import evaluate_model
    from styleerd.train.batches import windows
    from styleerd.train.config import TrainConfig
    from styleerd.train.fmd import reconstruction_degrees
    from styleerd.train.trainer import setup

    fmd, meta = ckpt.load_fmd()
    s = setup(TrainConfig(), str(shared_data), progress=False)
    test = windows(s.fs, s.data, "test", s.data.window)
    assert abs(reconstruction_degrees(fmd, s.data, test) - meta["test_reconstruction_deg"]) < 1e-3
    q = evaluate_model(ckpt.load_generator()[0], str(shared_data))
    print(q)
    # the floor compares two halves of the real windows (half the samples each, and FMD grows as
    # samples shrink), so a model's FMD may be under it: the shipped model's is 0.88 x
    assert 0.5 < q["fmd_over_floor"] < 10 and q["sra"] > 0.9 and 0 < q["cra"] <= 1
    assert q["sra_first_10"] <= q["sra_rest"] and q["jitter_ratio"] > 0
    # per target style: CRA next to the content recogniser on the same inputs; spreads
    styles = set(q["fmd_per_style"])
    assert (
        styles
        == set(q["cra_per_style"])
        == set(q["content_ceiling_per_style"])
        == set(q["sra_per_style"])
        == set(ckpt.load_generator()[0].config.styles)
    )
    assert all(0.5 < v <= 1 for v in q["content_ceiling_per_style"].values())
    assert 0 < q["spread"]["sra"] < 0.05 and 0 < q["spread"]["cra"] < 0.05 and 0 < q["spread"]["fmd"] < q["fmd"]
    # each style's CRA over its ceiling, resampled over that style's transfers: wider than the pooled CRA's
    assert set(q["cra_of_ceiling_spread_per_style"]) == styles
    assert all(q["spread"]["cra"] < v < 0.1 for v in q["cra_of_ceiling_spread_per_style"].values())
    assert q["realism_margin"] > 0 and q["worst_fmd_over_floor"] == round(
        max(q["fmd_per_style"][k] / q["fmd_floor_per_style"][k] for k in styles), 3
    )
    # the same on the validation split (choosing between models without the test set): other windows, other figures
    v = evaluate_model(ckpt.load_generator()[0], str(shared_data), split="val")
    val = windows(s.fs, s.data, "val", s.data.window)
    assert v["transfers"] != q["transfers"] and len(val.starts) != len(test.starts)
    assert set(v["fmd_per_style"]) == styles and v["fmd"] != q["fmd"] and v["realism_margin"] > 0


def test_bootstrap_spread_is_the_standard_error_of_a_mean():
    from styleerd.train.validation import bootstrap_spread

    x = np.random.default_rng(1).normal(0, 2.0, 400)
    sd = bootstrap_spread(len(x), lambda i: x[i].mean(), resamples=2000)
    assert abs(sd - x.std() / np.sqrt(len(x))) < 0.1 * x.std() / np.sqrt(len(x))


@pytest.mark.slow
def test_streamed_transfers_back_to_neutral_and_into_styles(shared_data, tmp_path):
    """`styleerd eval streamed`: whole test clips streamed as `transfer` runs them, read as
    they play; every styled source taken back to neutral, neutral into every style, labels
    given and inferred."""
    import json
    import sys

    from conftest import run_checked

    out = tmp_path / "streamed.json"
    run_checked([sys.executable, "-m", "styleerd.cli", "eval", "streamed", "--data", shared_data, "--json", out])
    r = json.loads(out.read_text())
    c = load_generator()[0].config
    assert set(r["transfers"]) == set(c.styles)
    assert set(r["transfers"][c.neutral_style]) == set(c.styles) - {c.neutral_style}
    n = r["summary"]
    print(n)
    for source, v in n["to_neutral"].items():
        assert v["given"] > 0.6 and v["inferred"] > 0.6, source
    assert n["into_styles_mean"]["given"] > 0.9
    for source, targets in r["transfers"].items():  # the misses, counted by what they were read as
        for target, v in targets.items():
            assert 0.5 < v["content_ceiling"] <= 1.0  # the content recogniser on the inputs themselves
            assert target not in v["missed_read_as"]
            assert sum(v["missed_read_as"].values()) == round((1 - v["given"]["sra"]) * v["windows"])
    # per target style, the played content over its ceiling: into neutral pooled over the sources' windows
    played = n["cra_of_ceiling"]
    assert set(played) == set(c.styles) and all(0.5 < v < 1.2 for v in played.values())
    back = [v[c.neutral_style] for k, v in r["transfers"].items() if k != c.neutral_style]
    pooled = sum(b["given"]["cra"] * b["windows"] for b in back) / sum(
        b["content_ceiling"] * b["windows"] for b in back
    )
    assert abs(played[c.neutral_style] - pooled) < 1e-4
    into = r["transfers"][c.neutral_style]["elderly"]
    assert abs(played["elderly"] - into["given"]["cra"] / into["content_ceiling"]) < 1e-4
    # the labeller reads each source's style by the clip's end
    pace = r["root_speed_by_content_and_style"]  # elderly performers walk and run slower than normal ones
    assert (
        pace["walk"]["elderly"] < 0.8 * pace["walk"]["normal"] and pace["run"]["elderly"] < 0.6 * pace["run"]["normal"]
    )
    read = r["labeller_reads_input_as_at_end"]
    assert sum(v.get(k, 0) for k, v in read.items()) / sum(sum(v.values()) for v in read.values()) > 0.9


@pytest.mark.slow
def test_cleanup_removes_skate_and_blending_removes_the_pop(shared_data):
    r = runtime_report(load_generator()[0], load_labeller()[0], str(shared_data))
    print(r)
    skate = r["foot_skate_cm_per_frame"]
    assert skate["streams"] > 100
    assert skate["cleaned_output"] < 0.2 * skate["raw_output"] and skate["cleaned_output"] <= 2 * skate["input"]
    # the root's speed stylised (transfer --root-speed): the root moves at another pace, the
    # cleanup still pins the planted feet where the moved body puts them
    assert (
        skate["root_speed_change"] > 0.1
        and skate["root_speed_ratio_range"][0] < 0.9
        and skate["root_speed_ratio_range"][1] > 1.1
    )
    assert (
        skate["cleaned_output_root_speed"] < 0.2 * skate["raw_output_root_speed"]
        and skate["cleaned_output_root_speed"] <= 2 * skate["input"]
    )
    sw = r["style_switch"]
    assert sw["blended_cm"] < sw["unblended_cm"] and sw["blended_cm"] < sw["normal_p99_cm"]
    assert r["labels"][30]["style"] >= 0.97


def test_misread_names_the_contents_a_style_loses_most_often():
    given = np.array([0, 0, 0, 0, 1, 1, 2])
    read = np.array([0, 1, 1, 2, 1, 0, 2])
    assert misread(given, read, ["walk", "turn", "wave"]) == {
        "walk -> turn": "2 of 4",
        "walk -> wave": "1 of 4",
        "turn -> walk": "1 of 2",
    }
    assert misread(given, given, ["walk", "turn", "wave"]) == {}
