"""Every take of cmu-sample, whole, through ``transfer`` as users run it (``styleerd.eval.corpus``)."""

import pytest

from styleerd.eval.corpus import every_take, take_figures
from styleerd.model.stored import load_generator_weights
from styleerd.runtime.offline import TransferOptions, transfer_motion


@pytest.fixture(scope="module")
def model():
    return load_generator_weights(None)


def test_every_cmu_sample_take_comes_back(shared_data, model):
    """Each of cmu-sample's 62 takes (two rigs, 60 and 120 fps; the Character Creator ones start with
    a frame of rest pose 2 m from the take): the identity transfer keeps the action (velocity
    correlation >= 0.9, error <= 1 cm) and so does elderly (>= 0.75), no foot under the floor.
    Before the transfer resampled the style's change rather than the poses, and the foot cleanup
    started afresh at a cut, subject 7's walks came back at a correlation as low as 0.21, their feet
    held back where the rest pose stood."""
    takes = every_take(model, str(shared_data), ("cmu-sample",))
    assert len(takes) == 62
    bad = []
    for clip in takes:
        for target, bar in (("normal", 0.9), ("elderly", 0.75)):
            out = transfer_motion(clip.motion, model, 30.0, TransferOptions({target: 1.0}, "normal"), where=clip.name)
            f = take_figures(clip, out, model)
            if f["correlation"] < bar or f["below_floor_cm"] > 1.0 or (target == "normal" and f["error_cm"] > 1.0):
                bad.append((clip.name, target, f))
    assert bad == []
