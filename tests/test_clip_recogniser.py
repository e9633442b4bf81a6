"""The second judge (``eval.clip_recogniser``): the kept recogniser is the one evaluations load, it
reads real test takes as their own style, and it tells a take from the same take's transfer."""

import numpy as np
import pytest

from styleerd.data.cache import prepare
from styleerd.data.features import features_to_motion, motion_features
from styleerd.eval import clip_recogniser as C
from styleerd.model.stored import load_generator_weights
from styleerd.runtime.offline import TransferOptions, transfer_motion


@pytest.mark.slow
def test_the_kept_clip_recogniser_reads_test_takes_and_transfers(shared_data):
    fs = prepare("bandai-namco-2", str(shared_data), progress=False)
    model = load_generator_weights(None)
    styles = list(model.config.input_styles)
    recogniser = C.loaded_or_trained(fs, styles)  # the kept one: training it again would take minutes
    J = fs.skeleton.n_joints
    test = fs.clips("test")
    read = [C.read_style(recogniser, fs.features[fs.frames(c)], J, styles) == str(fs.styles[c]) for c in test]
    assert np.mean(read) >= 0.85, np.mean(read)  # docs/clip-styles.md: 254 of 280
    take = next(c for c in test if str(fs.styles[c]) == "normal" and str(fs.contents[c]) == "walk")
    sl = fs.frames(take)
    motion = features_to_motion(fs.features[sl], fs.trajectory[sl], fs.skeleton, fs.params.fps)
    assert C.read_style(recogniser, fs.features[sl], J, styles) == "normal"
    elderly = transfer_motion(motion, model, fs.params.fps, TransferOptions({"elderly": 1.0}))
    assert C.read_style(recogniser, motion_features(elderly)[0], J, styles) == "elderly"
