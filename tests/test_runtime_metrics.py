"""The runtime figures of the shipped models on the test split (styleerd eval-runtime)."""

import pytest

from styleerd.eval.metrics import runtime_report
from styleerd.model.checkpoint import load_generator, load_labeller

pytestmark = pytest.mark.slow


def test_cleanup_removes_skate_and_blending_removes_the_pop(shared_data):
    r = runtime_report(load_generator()[0], load_labeller()[0], str(shared_data))
    print(r)
    skate = r["foot_skate_cm_per_frame"]
    assert skate["streams"] > 100
    assert skate["cleaned_output"] < 0.2 * skate["raw_output"] and skate["cleaned_output"] <= 2 * skate["input"]
    sw = r["style_switch"]
    assert sw["blended_cm"] < sw["unblended_cm"] and sw["blended_cm"] < sw["normal_p99_cm"]
    assert r["labels"][30]["style"] >= 0.97
