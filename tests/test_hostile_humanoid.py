"""The new doors of the humanoid mapping and the clip picking under hostile or careless input:
VRM / VRM Animation humanoids that point nowhere, animation names that are not there, joint
names of any kind (a hypothesis fuzzer), a joint map to write where it cannot be. Every case is
one line and exit 2 from the CLI, or the mapping's own ValueError, never a traceback; nothing is
written. The corpus is made here from a good file."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pygltflib as gl
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from styleerd.model.stored import load_generator_weights
from styleerd.motion.gltf import write_glb
from styleerd.motion.humanoid import body_parts, side_and_stem
from styleerd.motion.procedural import tpose_skeleton, walk
from styleerd.motion.retarget import joint_map
from styleerd.motion.skeleton import Skeleton

CLI = [sys.executable, "-m", "styleerd.cli", "transfer"]
BONES = {"Hips": "hips", "Spine2": "chest", "Head": "head", "LeftUpLeg": "leftUpperLeg", "LeftLeg": "leftLowerLeg"}


def run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, check=False, timeout=300)


def one_line_refusal(r: subprocess.CompletedProcess, *outputs) -> None:
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not any(o.exists() for o in outputs)


@pytest.fixture(scope="module")
def vrma(tmp_path_factory):
    """A VRM Animation made here: the demo walk's nodes, no skin, a humanoid naming them."""
    path = tmp_path_factory.mktemp("vrma") / "walk.vrma"
    write_glb(path, walk(1.0, fps=30.0))
    doc = gl.GLTF2().load_binary(str(path))
    doc.skins = []
    names = [n.name for n in doc.nodes]
    humanoid = {bone: {"node": names.index(joint)} for joint, bone in BONES.items()}
    doc.extensionsUsed = ["VRMC_vrm_animation"]
    doc.extensions = {"VRMC_vrm_animation": {"specVersion": "1.0", "humanoid": {"humanBones": humanoid}}}
    doc.save_binary(str(path))
    return path


def test_the_good_vrma_reads(vrma, tmp_path):
    r = run(vrma, "--style", "elderly", "-o", tmp_path / "out.vrma")
    assert r.returncode == 0, r.stderr


HUMANOIDS = {
    "a node that is a word": {"hips": {"node": "x"}},
    "a node past the end": {"hips": {"node": 10**9}},
    "a negative node": {"hips": {"node": -1}},
    "no node": {"hips": {}},
    "bones as a list": [{"bone": "hips", "node": 0}],
    "a bone that is a number": {"hips": 7},
    "no hips": {"head": {"node": 5}},
}


@pytest.mark.parametrize("case", list(HUMANOIDS))
def test_a_humanoid_pointing_nowhere_is_refused_in_one_line(vrma, tmp_path, case):
    doc = gl.GLTF2().load_binary(str(vrma))
    doc.extensions["VRMC_vrm_animation"]["humanoid"]["humanBones"] = HUMANOIDS[case]
    bad = tmp_path / "bad.vrma"
    doc.save_binary(str(bad))
    one_line_refusal(run(bad, "--style", "elderly", "-o", tmp_path / "out.vrma"), tmp_path / "out.vrma")


@pytest.mark.parametrize("name", ["Moonwalk", "", "x" * 10_000, "\u202e\u200b", "-1"])
def test_an_animation_that_is_not_there_is_refused_in_one_line(vrma, tmp_path, name):
    r = run(vrma, "--style", "elderly", "--animation", name, "-o", tmp_path / "out.glb")
    one_line_refusal(r, tmp_path / "out.glb")
    assert "the file has: styleerd" in r.stderr and len(r.stderr) < 1000


def test_a_joint_map_written_where_it_cannot_be_is_refused(vrma, tmp_path):
    (tmp_path / "folder").mkdir()
    one_line_refusal(run(vrma, "--write-joint-map", tmp_path / "folder"))
    one_line_refusal(run(vrma, "--write-joint-map", tmp_path / "no" / "such" / "map.json"), tmp_path / "no")
    r = run(vrma, "--write-joint-map", tmp_path / "map.json")
    assert r.returncode == 0 and json.loads((tmp_path / "map.json").read_text())["Hips"] == "Hips"


@pytest.fixture(scope="module")
def model():
    return load_generator_weights()


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.text(max_size=40), min_size=22, max_size=22), st.integers(0, 2**32 - 1))
def test_any_joint_names_map_or_fail_with_the_mappings_own_error(model, names, seed):
    """Random names (any unicode, empty, repeated) on the demo skeleton, some joints shuffled
    into other names' places: the parts found are joints of the skeleton, and a map either comes
    out or the error is a ValueError naming what is missing."""
    sk = tpose_skeleton()
    rng = np.random.default_rng(seed)
    keep = rng.random(sk.n_joints) < 0.5
    named = tuple(sk.names[j] if keep[j] else names[j] for j in range(sk.n_joints))
    other = Skeleton(named, sk.parents, sk.offsets, sk.channels)
    parts = body_parts(other)
    assert all(0 <= j < sk.n_joints for j in parts.values())
    for n in named:
        side_and_stem(n)
    try:
        joint_map(model.skeleton, other)
    except ValueError as e:
        assert str(e)
