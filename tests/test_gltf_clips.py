"""Every animation of a glTF character is stylised and keeps its name (RobotExpressive: 14 clips,
IK feet, a rig no map was written for); one can be picked; the input's can be kept beside the
new ones; the buffer holds nothing unused; the Khronos validator finds no more than in the input."""

import subprocess
import sys

import numpy as np
import pygltflib as gl
import pytest
from test_gltf_mesh import needs_node, validate

from styleerd.motion.gltf import read_gltf

CLI = [sys.executable, "-m", "styleerd.cli", "transfer"]


@pytest.fixture(scope="module")
def robot(shared_data):
    return shared_data / "characters" / "RobotExpressive.glb"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, check=False, timeout=600)


def used_everywhere(doc: gl.GLTF2) -> None:
    """Every accessor and buffer view is used, and the buffer is no longer than its views."""
    accessors = {x for a in doc.animations for s in a.samplers for x in (s.input, s.output)}
    accessors |= {s.inverseBindMatrices for s in doc.skins if s.inverseBindMatrices is not None}
    for m in doc.meshes:
        for p in m.primitives:
            for attributes in [p.attributes, *(p.targets or [])]:
                fields = attributes if isinstance(attributes, dict) else vars(attributes)
                accessors |= {v for v in fields.values() if isinstance(v, int)}
            accessors |= {p.indices} if p.indices is not None else set()
    assert accessors == set(range(len(doc.accessors)))
    views = {a.bufferView for a in doc.accessors} | {i.bufferView for i in doc.images if i.bufferView is not None}
    assert views == set(range(len(doc.bufferViews)))
    assert doc.buffers[0].byteLength <= sum(v.byteLength + 3 for v in doc.bufferViews)


def test_every_clip_is_stylised_under_its_own_name(robot, tmp_path):
    r = run(str(robot), "--style", "elderly", "-o", str(tmp_path / "out.glb"))
    assert r.returncode == 0, r.stderr
    src, out = gl.GLTF2().load_binary(str(robot)), gl.GLTF2().load_binary(str(tmp_path / "out.glb"))
    names = [a.name for a in src.animations]
    assert len(names) == 14 and [a.name for a in out.animations] == names
    assert "in 14 animations" in r.stdout
    used_everywhere(out)
    assert [n.name for n in out.nodes] == [n.name for n in src.nodes] and len(out.meshes) == len(src.meshes)
    for name in ("Walking", "Punch"):
        a, b = read_gltf(robot, name).motion, read_gltf(tmp_path / "out.glb", name).motion
        assert a.n_frames == b.n_frames and not np.allclose(a.rotations, b.rotations, atol=1e-3)


def test_one_clip_picked_the_originals_kept_and_bvh_needs_one(robot, tmp_path):
    r = run(str(robot), "--style", "elderly", "--animation", "Wave", "-o", str(tmp_path / "wave.glb"))
    assert r.returncode == 0, r.stderr
    assert [a.name for a in gl.GLTF2().load_binary(str(tmp_path / "wave.glb")).animations] == ["Wave"]
    r = run(str(robot), "--style", "elderly", "--keep-original", "-o", str(tmp_path / "both.glb"))
    assert r.returncode == 0, r.stderr
    both = gl.GLTF2().load_binary(str(tmp_path / "both.glb"))
    names = [a.name for a in gl.GLTF2().load_binary(str(robot)).animations]
    assert [a.name for a in both.animations] == names + [f"{n}-elderly" for n in names]
    used_everywhere(both)
    kept, original = read_gltf(tmp_path / "both.glb", "Dance").motion, read_gltf(robot, "Dance").motion
    assert np.array_equal(kept.rotations, original.rotations)  # the input's own clip, untouched
    r = run(str(robot), "--style", "elderly", "-o", str(tmp_path / "x.bvh"))
    assert r.returncode == 2 and "pick one with --animation NAME" in r.stderr and not (tmp_path / "x.bvh").exists()
    r = run(str(robot), "--style", "elderly", "--animation", "Walking", "-o", str(tmp_path / "walk.bvh"))
    assert r.returncode == 0, r.stderr
    r = run(str(robot), "--style", "elderly", "--animation", "Moonwalk", "-o", str(tmp_path / "y.glb"))
    assert r.returncode == 2 and "no animation 'Moonwalk'; the file has: Dance, Death" in r.stderr


@needs_node
def test_the_validator_finds_nothing_the_input_did_not_have(robot, tmp_path):
    assert run(str(robot), "--style", "exhausted", "--keep-original", "-o", str(tmp_path / "o.glb")).returncode == 0

    def counts(path):
        issues = validate(path)["issues"]
        return issues["numErrors"], issues["numWarnings"], sorted({m["code"] for m in issues["messages"]})

    assert counts(tmp_path / "o.glb") == counts(robot)


def test_the_api_picks_a_clip_and_keeps_the_originals(robot, tmp_path):
    import styleerd

    wave = styleerd.transfer(robot, "elderly", output=tmp_path / "wave.glb", animation="Wave")
    assert wave.n_frames == read_gltf(robot, "Wave").motion.n_frames
    styleerd.transfer(robot, "elderly", output=tmp_path / "both.glb", animation="Wave", keep_original=True)
    names = [a.name for a in gl.GLTF2().load_binary(str(tmp_path / "both.glb")).animations]
    assert names[-1] == "Wave-elderly" and len(names) == 15


def test_info_lists_a_characters_animations_skeleton_and_mapping(shared_data):
    """What ``transfer`` would read, before running it: every animation (frames, rate, length), the
    skeleton, the joint mapping (a VRM humanoid's); a character with no animation says what it is for."""

    def info(name: str) -> str:
        r = subprocess.run(
            [sys.executable, "-m", "styleerd.cli", "info", str(shared_data / "characters" / name)],
            capture_output=True,
            text=True,
            check=False,
            timeout=300,
        )
        assert r.returncode == 0 and not r.stderr.strip(), r.stderr
        return r.stdout

    out = info("RobotExpressive.glb")
    first, *lines = out.splitlines()
    assert first.endswith("RobotExpressive.glb: glTF, 43 joints, 14 animation(s)")
    doc = gl.GLTF2.load(str(shared_data / "characters" / "RobotExpressive.glb"))
    assert [line.split(":")[0].strip() for line in lines[:14]] == [repr(a.name) for a in doc.animations]
    assert "  'Walking': 24 frames at 24 fps (1.00 s)" in lines
    assert "joint mapping (model <- input):" in lines and "            Hips <- Body" in lines
    out = info("test.vrma")
    assert "VRM Animation, a VRM humanoid, 51 joints, 1 animation(s)" in out and "31 frames at 10 fps" in out
    assert any(line.endswith("UpperLeg_L <- leftUpperLeg") for line in out.splitlines())
    out = info("Godette.vrm")
    assert "VRM, a VRM humanoid, 68 joints, 0 animation(s)" in out
    assert "no animation: a character to put a motion on (transfer --onto)" in out


def test_a_bvhs_animation_is_named_after_its_file_in_glb_and_vrma(tmp_path):
    """A .glb or .vrma written from a BVH names its animation after the BVH (it was 'styleerd' for
    every file, so two clips loaded into one engine had one name)."""
    from styleerd.motion import bvh
    from styleerd.motion.procedural import walk

    bvh.write(tmp_path / "slow walk.bvh", walk(2.0, fps=30.0))
    for kind in ("glb", "vrma"):
        out = tmp_path / f"out.{kind}"
        r = run(str(tmp_path / "slow walk.bvh"), "--style", "elderly", "-o", str(out))
        assert r.returncode == 0, r.stderr
        assert [a.name for a in gl.GLTF2().load_binary(str(out)).animations] == ["slow walk"]
