"""Style per body part: each part takes its own target or the input's own motion."""

import subprocess
import sys

import numpy as np
import pytest

from styleerd.errors import StyleERDError
from styleerd.model.stored import load_generator_weights
from styleerd.motion import bvh, quat
from styleerd.motion.retarget import BODY_PARTS, part_joints
from styleerd.runtime.stylizer import StreamStylizer, part_targets


@pytest.fixture(scope="module")
def model():
    return load_generator_weights()


@pytest.fixture(scope="module")
def walk(model):
    from styleerd.motion.procedural import walk
    from styleerd.motion.retarget import to_target
    from styleerd.runtime.offline import map_skeleton

    source = walk(seconds=2.0, fps=30.0)
    return to_target(source, map_skeleton(source.skeleton, model, first_pose=source.rotations[0]))


def run(model, motion, target, parts=None, backend="numpy", n=None):
    st = StreamStylizer(model, "normal", "walk", target, backend=backend, parts=parts)
    return np.stack([st.step(motion.rotations[t], motion.positions[t])[0][0] for t in range(n or motion.n_frames)])


def test_every_joint_is_in_exactly_one_part(model):
    parts = part_joints(model.skeleton)
    assert set(parts) == set(BODY_PARTS)
    joints = np.concatenate(list(parts.values()))
    assert sorted(joints.tolist()) == list(range(model.skeleton.n_joints))
    names = {p: {model.skeleton.names[j] for j in js} for p, js in parts.items()}
    assert {"UpperLeg_L", "Toes_R"} <= names["legs"] and {"Shoulder_L", "Hand_R"} <= names["arms"]
    assert names["torso"] == {"Hips", "Spine", "Chest"} and names["head"] == {"Neck", "Head"}


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_each_part_is_its_targets_output_and_input_parts_are_the_input(model, walk, backend):
    parts = part_joints(model.skeleton)
    mixed = run(model, walk, {"exhausted": 1.0}, {"legs": "elderly", "arms": "input"}, backend)
    exhausted = run(model, walk, {"exhausted": 1.0}, backend=backend)
    elderly = run(model, walk, {"elderly": 1.0}, backend=backend)
    legs, arms = parts["legs"], parts["arms"]
    rest = np.concatenate([parts["torso"], parts["head"]])
    assert np.abs(mixed[:, legs] - elderly[:, legs]).max() <= 1e-6
    assert np.abs(mixed[:, rest] - exhausted[:, rest]).max() <= 1e-6
    assert np.abs(mixed[:, arms] - quat.normalize(walk.rotations[:, arms])).max() <= 1e-12
    assert np.abs(elderly[:, legs] - exhausted[:, legs]).max() > 0.05  # the parts differ: the test can fail


def test_parts_sharing_a_target_share_a_pass_and_reset_covers_every_pass(model, walk):
    st = StreamStylizer(
        model, "normal", "walk", {"active": 1.0}, n_streams=2, parts="legs=elderly,head=elderly,torso=active:0.5"
    )
    assert len(st.part_passes) == 2 and st.backend.n == 6
    first = [st.step(np.stack([walk.rotations[t]] * 2), np.stack([walk.positions[t]] * 2))[0] for t in range(5)]
    st.reset([1])
    again = st.step(np.stack([walk.rotations[0]] * 2), np.stack([walk.positions[0]] * 2))[0]
    assert np.abs(again[1] - first[0][1]).max() <= 1e-6  # stream 1 starts over in every pass
    assert np.abs(again[0] - first[0][0]).max() > 1e-4  # stream 0 goes on


def test_parts_stay_online(model, walk):
    """Perturbing a future frame changes no earlier output."""
    parts = {"legs": "elderly", "arms": "input"}
    base = run(model, walk, {"exhausted": 1.0}, parts, n=20)
    changed = walk[:20]
    changed.rotations = changed.rotations.copy()
    changed.rotations[15] = quat.normalize(changed.rotations[15] + 0.3)
    other = run(model, changed, {"exhausted": 1.0}, parts, n=20)
    assert np.array_equal(base[:15], other[:15]) and not np.allclose(base[15:], other[15:])


@pytest.mark.parametrize(
    "spec, message",
    [
        ("tail=elderly", "unknown body part 'tail'"),
        ("legs", "give part=style"),
        ("legs=angry", "unknown style 'angry'"),
        ("legs=elderly:lots", "intensity 'lots' is not a number"),
        ("legs=elderly:3", "intensity 3 is outside"),
    ],
)
def test_bad_part_specs_are_named(model, spec, message):
    with pytest.raises(StyleERDError, match=message):
        part_targets(model, spec)


def test_cli_transfer_with_parts(tmp_path):
    from styleerd.motion.procedural import walk

    src = tmp_path / "walk.bvh"
    bvh.write(src, walk(seconds=1.0, fps=30.0))
    out = tmp_path / "out.bvh"
    ok = subprocess.run(
        [
            sys.executable,
            "-m",
            "styleerd.cli",
            "transfer",
            str(src),
            "--style",
            "exhausted",
            "--parts",
            "legs=elderly,arms=input",
            "-o",
            str(out),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert ok.returncode == 0, ok.stderr
    assert bvh.read(out).n_frames == bvh.read(src).n_frames
    bad = subprocess.run(
        [
            sys.executable,
            "-m",
            "styleerd.cli",
            "transfer",
            str(src),
            "--style",
            "exhausted",
            "--parts",
            "wings=elderly",
            "-o",
            str(tmp_path / "bad.bvh"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert bad.returncode == 2 and "unknown body part 'wings'" in bad.stderr and "Traceback" not in bad.stderr
    assert not (tmp_path / "bad.bvh").exists()
