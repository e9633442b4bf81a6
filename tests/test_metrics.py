"""The evaluation metrics: the Fréchet distance against scipy's matrix square root, the
shipped FMD extractor against its record, the quality and runtime figures of the shipped
models on the test split."""

import numpy as np
import pytest
import scipy.linalg

from styleerd.eval.metrics import frechet_distance, runtime_report
from styleerd.model import checkpoint as ckpt
from styleerd.model.checkpoint import load_generator, load_labeller


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
    assert 1.0 < q["fmd_over_floor"] < 10 and q["sra"] > 0.9 and 0 < q["cra"] <= 1
    assert q["sra_first_10"] <= q["sra_rest"] and q["jitter_ratio"] > 0


@pytest.mark.slow
def test_cleanup_removes_skate_and_blending_removes_the_pop(shared_data):
    r = runtime_report(load_generator()[0], load_labeller()[0], str(shared_data))
    print(r)
    skate = r["foot_skate_cm_per_frame"]
    assert skate["streams"] > 100
    assert skate["cleaned_output"] < 0.2 * skate["raw_output"] and skate["cleaned_output"] <= 2 * skate["input"]
    sw = r["style_switch"]
    assert sw["blended_cm"] < sw["unblended_cm"] and sw["blended_cm"] < sw["normal_p99_cm"]
    assert r["labels"][30]["style"] >= 0.97
