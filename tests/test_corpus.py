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
            f = take_figures(clip, {target: out}, model)[target]
            if f["correlation"] < bar or f["below_floor_cm"] > 1.0 or (target == "normal" and f["error_cm"] > 1.0):
                bad.append((clip.name, target, f))
    assert bad == []


def test_a_run_and_a_dash_keep_their_planted_feet(shared_data, model):
    """Bandai-Namco-1's masculine run and dash (2 s, contacts of a few frames at 30 fps), as themselves
    and into elderly: planted feet slide no faster than the input's own (``feet_figures``' median).
    The cleanup reads a contact from the input ankle's move into a frame; when it anchored the foot
    where the output had it on that frame, not on the frame before, the first move of every contact
    slid: on the run 22-83 cm/s faster than the input's (``styleerd eval corpus`` at ``3626610``)."""
    takes = [
        c
        for c in every_take(model, str(shared_data), ("bandai-namco-1",))
        if c.name.startswith(("dataset-1_run_masculinity", "dataset-1_dash_masculinity"))
    ]
    assert len(takes) >= 2
    for clip in takes:
        for target, given in (("masculine", "masculine"), ("elderly", None)):
            out = transfer_motion(clip.motion, model, 30.0, TransferOptions({target: 1.0}, given), where=clip.name)
            slide = take_figures(clip, {target: out}, model)[target]["slide_cm_s"]
            assert slide["output"] <= slide["input"], (clip.name, target, slide)
