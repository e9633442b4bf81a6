"""The reference host loop of docs/ONNX.md (examples/onnx_host.py: numpy + onnxruntime, with
styleerd made unimportable) gives styleerd's own stylizer's output from the exported graph."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from styleerd.model.stored import load_generator_weights
from styleerd.motion import quat
from styleerd.motion.procedural import walk
from styleerd.motion.retarget import to_target
from styleerd.runtime.offline import map_skeleton, run_stream
from styleerd.runtime.onnx_export import export
from styleerd.runtime.stylizer import StreamStylizer

HOST = Path(__file__).resolve().parents[1] / "examples" / "onnx_host.py"
# the script runs with styleerd blocked: an import of it anywhere fails
WITHOUT_STYLEERD = (
    "import runpy, sys; sys.modules['styleerd'] = None; sys.argv = sys.argv[1:]; "
    "runpy.run_path(sys.argv[0], run_name='__main__')"
)


@pytest.mark.parametrize(
    "form, familiar, style, guard",
    [("lstm", None, "elderly", False), ("plain", (9.0, 15.0), "elderly", False), ("lstm", None, "active", True)],
)
def test_reference_host_loop_equals_the_stylizer(tmp_path, form, familiar, style, guard):
    """Also with a model's own familiar range (``styleerd familiar``), which the host reads from the
    export, and on a walk with the fists held at the chin into active, whose posture raises the hands
    past the eyes (the host cuts their rise as the stylizer does)."""
    model = load_generator_weights()
    if familiar:
        model = dataclasses.replace(model, familiar=familiar)
    export(model, tmp_path / "stylizer.onnx", form)
    source = walk(seconds=3.0, fps=30.0, guard=guard)
    on_model = to_target(source, map_skeleton(source.skeleton, model, first_pose=source.rotations[0]))
    np.savez(tmp_path / "poses.npz", rotations=on_model.rotations, positions=on_model.positions, fps=on_model.fps)
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            WITHOUT_STYLEERD,
            str(HOST),
            str(tmp_path / "stylizer.onnx"),
            str(tmp_path / "poses.npz"),
            str(tmp_path / "out.npz"),
            "--style",
            style,
            "--input-style",
            "normal",
            "--content",
            "walk",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    host = np.load(tmp_path / "out.npz")["rotations"]
    stylizer = StreamStylizer(model, "normal", "walk", {style: 1.0}, fps=on_model.fps, backend="onnx")
    ours = run_stream(stylizer, on_model).rotations
    # the generated walk is partly unfamiliar: the network's pose, the input turned by the posture, and blends;
    # with the guard, wholly: the input turned by the posture
    unfamiliar = stylizer.unfamiliar_sum[0] / stylizer.frames[0]
    assert model.posture is not None and (unfamiliar > 0.99 if guard else 0.2 < unfamiliar < 0.8)
    assert host.shape == ours.shape
    assert np.degrees(quat.angle_between(host, ours)).max() < 1e-2
    assert np.degrees(quat.angle_between(host, on_model.rotations)).max() > 5.0  # stylised, not the input


def test_the_hosts_blend_with_the_stylizers_thresholds():
    """The two standalone hosts (no styleerd import) carry the stylizer's default unfamiliarity
    thresholds and how far their weight may move a frame as numbers, for an export without a model's
    own (``familiar_degrees``, ``unfamiliar_rise_release``)."""
    import re

    from styleerd.model.config import FAMILIAR, RELEASE, RISE, UNFAMILIAR

    root = Path(__file__).resolve().parents[1]
    for path in (HOST, root / "styleerd/serve/static/engine.js"):
        text = path.read_text()
        found = re.search(r"FAMILIAR, UNFAMILIAR\]? = \[?([\d.]+), ([\d.]+)", text)
        assert found and tuple(map(float, found.groups())) == (FAMILIAR, UNFAMILIAR), path
        found = re.search(r"RISE, RELEASE\]? = \[?([\d.]+), ([\d.]+)", text)
        assert found and tuple(map(float, found.groups())) == (RISE, RELEASE), path
