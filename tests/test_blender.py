"""FBX and Blender, as an animator meets them: ``pip install styleerd[blender]`` (Blender's own
``bpy`` module) into a fresh virtualenv, a Mixamo-named character made in Blender (bones rolled
their own ways, a skinned body) exported as FBX, stylised to FBX by the command line and by the
add-on's operator, re-imported in Blender and compared, bone by bone and frame by frame, with a
BVH run of the same motion (tests/blender_checks.py does the Blender side)."""

from __future__ import annotations

import importlib.util
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygltflib as gl
import pytest
from conftest import run_checked

from styleerd.motion import bvh

CHECKS = Path(__file__).with_name("blender_checks.py")
# mathutils computes in float32: two equal rotations measure up to ~0.03 deg apart
TOLERANCE_DEG = 0.1


@pytest.fixture(scope="module")
def blender_venv(wheel, tmp_path_factory) -> Path:
    if sys.version_info[:2] != (3, 11) or platform.machine() not in ("x86_64", "AMD64", "arm64"):
        pytest.skip(
            "bpy 4.2-5.0 is built for Python 3.11 on x86_64 / Apple arm64 only, not Python "
            f"{sys.version_info[0]}.{sys.version_info[1]} on {platform.machine()}"
        )
    if os.environ.get("STYLEERD_BLENDER_VENV"):  # one with styleerd[blender] in it already (while developing)
        return Path(os.environ["STYLEERD_BLENDER_VENV"])
    venv = tmp_path_factory.mktemp("blender") / "venv"
    run_checked([sys.executable, "-m", "venv", venv])
    run_checked(
        [venv / "bin/python", "-m", "pip", "install", "--quiet", f"{wheel}[blender]"]
    )  # bpy from PyPI (about 360 MB)
    return venv


def _blender(venv: Path, what: str, work: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = run_checked([venv / "bin/python", CHECKS, what, work], cwd=work, env=env).stdout
    return json.loads(next(line for line in out.splitlines() if line.startswith("RESULT "))[7:])


@pytest.fixture(scope="module")
def character(blender_venv, tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("character")
    made = _blender(blender_venv, "make", work)
    assert made["keyed_error_deg"] < TOLERANCE_DEG  # the character moves as walk.bvh does
    cli = blender_venv / "bin/styleerd"
    run_checked([cli, "transfer", "walk.bvh", "--style", "elderly", "-o", "ref.bvh"], cwd=work)
    return work


def test_fbx_to_fbx_matches_the_bvh_run_and_keeps_the_character(blender_venv, character):
    done = run_checked(
        [blender_venv / "bin/styleerd", "transfer", "walk.fbx", "--style", "elderly", "-o", "out.fbx"], cwd=character
    )
    assert "wrote out.fbx: 120 frames" in done.stdout
    result = _blender(blender_venv, "compare", character)
    assert result["bones"] == result["source_bones"] and len(result["bones"]) == 22
    assert result["frames"] == bvh.read(character / "walk.bvh").n_frames
    assert result["meshes"] == result["source_meshes"] == ["Body"]  # the skinned body comes through
    assert result["stylised_change_deg"] > 10.0  # the output is stylised, not the input
    assert result["max_error_deg"] < TOLERANCE_DEG, result


def test_fbx_to_bvh_and_glb_and_bvh_to_fbx(blender_venv, character):
    cli = blender_venv / "bin/styleerd"
    run_checked([cli, "transfer", "walk.fbx", "--style", "elderly", "-o", "from-fbx.bvh"], cwd=character)
    ref, out = bvh.read(character / "ref.bvh"), bvh.read(character / "from-fbx.bvh")
    assert out.n_frames == ref.n_frames and out.fps == pytest.approx(ref.fps)
    assert [n.removeprefix("mixamorig:") for n in out.skeleton.names] == list(ref.skeleton.names)
    run_checked([cli, "transfer", "walk.fbx", "--style", "elderly", "-o", "from-fbx.glb"], cwd=character)
    assert (character / "from-fbx.glb").read_bytes()[:4] == b"glTF"
    run_checked([cli, "transfer", "walk.bvh", "--style", "elderly", "-o", "from-bvh.fbx"], cwd=character)
    assert (character / "from-bvh.fbx").read_bytes()[:18] == b"Kaydara FBX Binary"
    lines = run_checked([cli, "info", "walk.fbx"], cwd=character).stdout.splitlines()
    assert lines[0] == f"walk.fbx: FBX, {len(ref.skeleton.names)} joints, 1 animation(s)"
    assert lines[1].endswith(f": {ref.n_frames} frames at {ref.fps:.6g} fps ({ref.n_frames / ref.fps:.2f} s)")
    assert "            Hips <- mixamorig:Hips" in lines
    take = lines[1].split("'")[1]  # the glb's animation is named after the take
    assert [a.name for a in gl.GLTF2().load_binary(str(character / "from-fbx.glb")).animations] == [take]


def test_addon_writes_a_new_action_matching_the_bvh_run(blender_venv, character):
    result = _blender(blender_venv, "addon", character)
    assert result["status"] == ["FINISHED"]
    assert (
        result["action"] == f"{result['original']}-elderly"
        and sorted([result["original"], result["action"]]) == result["actions"]
    )
    assert result["original_kept"]
    assert result["frames"] == 120 and result["max_error_deg"] < TOLERANCE_DEG, result


def test_every_take_of_an_fbx_is_stylised_under_its_own_name(blender_venv, character):
    """An FBX of two takes (the walk, and the walk played backwards): each stylised under its own name
    (the walk exactly as the BVH run), the mesh kept; with --keep-original the originals beside them as
    NAME-STYLE; one picked with --animation for a BVH, which holds one; an unknown one refused."""
    cli = blender_venv / "bin/styleerd"
    assert _blender(blender_venv, "two-takes", character)["takes"] == ["Back", "Walk"]
    run_checked([cli, "transfer", "two.fbx", "--style", "elderly", "-o", "two-out.fbx"], cwd=character)
    out = _blender(blender_venv, "takes-of:two-out.fbx", character)
    assert sorted(out["takes"]) == ["Back", "Walk"] and out["meshes"] == ["Body"]
    assert out["takes"]["Walk"]["error_vs_ref_deg"] < TOLERANCE_DEG and out["takes"]["Back"]["frames"] == 120
    assert out["takes"]["Back"]["error_vs_ref_deg"] > 10.0  # its own motion, not the walk's
    run_checked(
        [cli, "transfer", "two.fbx", "--style", "elderly", "--keep-original", "-o", "two-keep.fbx"], cwd=character
    )
    kept = _blender(blender_venv, "takes-of:two-keep.fbx", character)["takes"]
    assert sorted(kept) == ["Back", "Back-elderly", "Walk", "Walk-elderly"]
    assert kept["Walk-elderly"]["error_vs_ref_deg"] < TOLERANCE_DEG and kept["Walk"]["error_vs_ref_deg"] > 10.0
    refused = subprocess.run(
        [cli, "transfer", "two.fbx", "--style", "elderly", "-o", "two.bvh"],
        cwd=character,
        capture_output=True,
        text=True,
        check=False,
    )
    assert refused.returncode == 2 and "pick one with --animation NAME" in refused.stderr
    run_checked(
        [cli, "transfer", "two.fbx", "--style", "elderly", "--animation", "Walk", "-o", "walk-take.bvh"], cwd=character
    )
    ref, take = bvh.read(character / "ref.bvh"), bvh.read(character / "walk-take.bvh")
    assert take.n_frames == ref.n_frames
    unknown = subprocess.run(
        [cli, "transfer", "two.fbx", "--style", "elderly", "--animation", "Run", "-o", "run.bvh"],
        cwd=character,
        capture_output=True,
        text=True,
        check=False,
    )
    assert unknown.returncode == 2 and "no animation 'Run'; it has: 'Back', 'Walk'" in unknown.stderr


def test_a_motion_onto_an_fbx_character_and_an_fbx_take_onto_a_glb(blender_venv, character, shared_data):
    """--onto CHARACTER.fbx: the stylised BVH walk on the character's own armature (the same rig: as
    the BVH run), its skinned body kept, the take named after the clip, whether or not the character
    has an animation of its own; an FBX's take onto a GLB
    character (RobotExpressive) as one of its animations; a glTF character cannot take an .fbx out."""
    cli = blender_venv / "bin/styleerd"
    run_checked(
        [cli, "transfer", "walk.bvh", "--style", "elderly", "--onto", "walk.fbx", "-o", "onto.fbx"], cwd=character
    )
    onto = _blender(blender_venv, "takes-of:onto.fbx", character)
    assert list(onto["takes"]) == ["walk"] and onto["meshes"] == ["Body"]
    assert onto["takes"]["walk"]["error_vs_ref_deg"] < TOLERANCE_DEG
    assert _blender(blender_venv, "still", character)["actions"] == 0  # the character with no animation of its own
    run_checked(
        [cli, "transfer", "walk.bvh", "--style", "elderly", "--onto", "still.fbx", "-o", "on-still.fbx"], cwd=character
    )
    on_still = _blender(blender_venv, "takes-of:on-still.fbx", character)
    assert list(on_still["takes"]) == ["walk"] and on_still["takes"]["walk"]["error_vs_ref_deg"] < TOLERANCE_DEG
    robot = shared_data / "characters" / "RobotExpressive.glb"
    done = run_checked(
        [cli, "transfer", "walk.fbx", "--style", "elderly", "--onto", robot, "-o", "robot.glb"], cwd=character
    )
    assert "1 animation(s) on RobotExpressive.glb" in done.stdout
    refused = subprocess.run(
        [cli, "transfer", "walk.bvh", "--style", "elderly", "--onto", robot, "-o", "robot.fbx"],
        cwd=character,
        capture_output=True,
        text=True,
        check=False,
    )
    assert refused.returncode == 2 and "onto an FBX character" in refused.stderr


def test_an_fbx_character_for_the_viewer(blender_venv, character):
    """The viewer's server with Blender: an FBX avatar made a GLB, its humanoid found and its T-pose
    set on the GLB's nodes: arms out to the sides at one height, left hand on +X, feet below the hips."""
    got = _blender(blender_venv, "fbx-avatar", character)
    at = {k: np.array(v) for k, v in got["at"].items()}
    assert got["glb"] == "glTF" and {"hips", "head", "leftHand", "rightHand", "leftFoot"} <= set(got["bones"])
    assert at["leftHand"][0] > 0.3 and at["rightHand"][0] < -0.3 and abs(at["leftHand"][1] - at["rightHand"][1]) < 0.02
    assert at["leftFoot"][1] < at["hips"][1] - 0.5 < at["head"][1]


def test_fbx_errors_are_one_line(blender_venv, character, tmp_path):
    """Junk, and a real FBX cut short at several lengths, an ASCII FBX of garbage, an empty file:
    each is one line on stderr (Blender's importer prints its own traceback, which must not reach
    the user), naming the file, and nothing is written."""
    good = (character / "walk.fbx").read_bytes()
    (tmp_path / "junk.fbx").write_bytes(b"Kaydara FBX Binary  \x00" + bytes(64))
    broken = {f"cut{k}.fbx": good[: len(good) * k // 8] for k in (1, 3, 5, 7)}
    broken |= {"ascii.fbx": b"; FBX 7.4.0 project file\nFBXHeaderExtension:  {\n garbage", "empty.fbx": b""}
    for name, data in broken.items():
        (tmp_path / name).write_bytes(data)
    cases = [(["junk.fbx", "-o", "x.fbx"], "junk.fbx"), (["junk.fbx", "-o", "x.vrm"], "must be .fbx, .bvh or .glb")]
    cases += [([name, "-o", "x.bvh"], name) for name in broken]
    for args, message in cases:
        done = subprocess.run(
            [blender_venv / "bin/styleerd", "transfer", *args, "--style", "elderly"],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        assert done.returncode == 2 and message in done.stderr and "Traceback" not in done.stderr, done.stderr
        assert len(done.stderr.strip().splitlines()) == 1 and "Location:" not in done.stderr, (
            args,
            done.stderr[-3000:],
        )
        assert not list(tmp_path.glob("x.*"))


def test_fbx_without_blender_says_how_to_get_it(tmp_path):
    (tmp_path / "a.fbx").write_bytes(b"x")
    done = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "transfer", "a.fbx", "--style", "elderly", "-o", "b.bvh"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    if importlib.util.find_spec("bpy") is not None:
        pytest.skip("bpy is installed in this environment: the message for its absence cannot show")
    assert done.returncode == 2 and "styleerd[blender]" in done.stderr and "Traceback" not in done.stderr, done.stderr
    assert not list(tmp_path.glob("b.*"))
