"""A style added to a trained model (``styleerd add-style``): every old target's output is
bit-identical on every backend, the new style works wherever a model is used (transfer,
styles, the server's labels, ONNX export with parity), bad requests are one clear error, and
the command itself trains from clips on a skeleton that is not the model's."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from styleerd.errors import StyleERDError
from styleerd.model import checkpoint as ckpt
from styleerd.model.stored import generator_weights, load_generator_weights
from styleerd.motion import bvh
from styleerd.motion.procedural import rig_variants, walk
from styleerd.runtime.backends import make_backend
from styleerd.runtime.onnx_export import step_graph
from styleerd.runtime.stylizer import StreamStylizer
from styleerd.train.add_style import with_added_style

CLI = [sys.executable, "-m", "styleerd.cli"]


@pytest.fixture(scope="module")
def models():
    """The shipped model, and it with a style 'sneaky' whose branch and decoder row were
    moved away from the style it started from (so it is a style of its own)."""
    base, meta = ckpt.load_generator()
    added = with_added_style(base, "sneaky", "elderly")
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for p in [*added.branches[-1].parameters(), added.decoder_added]:
            p.add_(0.05 * torch.randn(p.shape, generator=g))
        added.branch_h0[-1].add_(0.1 * torch.randn(added.branch_h0[-1].shape, generator=g))
    return base, added, meta


def _frames(model, n: int = 40, streams: int = 3, seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    c = model.config
    x = rng.normal(0, 1, (n, streams, c.feature_dim)).astype(np.float32)
    style = np.eye(len(c.input_styles), dtype=np.float32)[rng.integers(0, len(c.input_styles), streams)]
    content = np.eye(len(c.contents), dtype=np.float32)[rng.integers(0, len(c.contents), streams)]
    return x, style, content


def _run(model, backend: str, x, style, content, target) -> np.ndarray:
    b = make_backend(backend, generator_weights(model), x.shape[1])
    return np.stack([b.step(x[t], style, content, target)[0] for t in range(len(x))])


@pytest.mark.parametrize("backend", ["torch", "numpy", "numba"])
def test_old_targets_are_bit_identical_on_every_backend(models, backend):
    base, added, _ = models
    x, style, content = _frames(base)
    n_old = len(base.config.styles)
    targets = {
        "one style each": np.eye(n_old, dtype=np.float32)[[1, 2, 5]],
        "a mixture and an intensity": np.array(
            [[0.5, 0.5, 0, 0, 0, 0, 0], [0, 1.7, 0, 0, 0, 0, 0], [0, 0, 0.3, 0.3, 0, 0.4, 0]], np.float32
        ),
    }
    for name, t in targets.items():
        before = _run(base, backend, x, style, content, t)
        after = _run(added, backend, x, style, content, np.concatenate([t, np.zeros((3, 1), np.float32)], 1))
        assert np.array_equal(before, after), f"{backend}, {name}: max difference {np.abs(before - after).max()}"


def test_the_added_style_is_its_own_and_backends_agree_on_it(models):
    base, added, _ = models
    x, style, content = _frames(base)
    t = np.zeros((3, len(added.config.styles)), np.float32)
    t[:, -1] = [1.0, 0.5, 1.5]
    t[1, 1] = 0.5  # half sneaky, half elderly
    ref = _run(added, "torch", x, style, content, t)
    for backend in ("numpy", "numba", "onnx", "onnx-plain"):
        np.testing.assert_allclose(_run(added, backend, x, style, content, t), ref, atol=1e-4, err_msg=backend)
    like = t.copy()
    like[:, 1], like[:, -1] = like[:, 1] + like[:, -1], 0.0  # the same weights on the style it started from
    assert np.abs(_run(added, "torch", x, style, content, like) - ref).max() > 1e-2


@pytest.mark.parametrize("loops", [False, True])
def test_the_numba_backends_loops_and_blas_paths_take_the_added_style(models, loops):
    """Either path of the compiled step's products, compiled loops or BLAS calls, takes the added
    style's decoder rows: equal to the numpy backend's."""
    from styleerd.runtime.calibration import EngineSettings, StepChoice
    from styleerd.runtime.compiled import CompiledBackend

    _, added, _ = models
    n = 41
    x, style, content = _frames(added, n=6, streams=n)
    t = np.eye(len(added.config.styles), dtype=np.float32)[np.arange(n) % len(added.config.styles)]
    t[::3, -1] += 0.5  # some mixtures with the added style
    choice = StepChoice(16, loops, 1)
    b = CompiledBackend(generator_weights(added), n, settings=EngineSettings((1,), (choice,), (choice,), "test"))
    got = np.stack([b.step(x[k], style, content, t)[0] for k in range(len(x))])
    np.testing.assert_allclose(got, _run(added, "numpy", x, style, content, t), atol=1e-5)


def test_onnx_graph_of_the_added_style_alone(models):
    _, added, _ = models
    proto = step_graph(generator_weights(added), "lstm", ("sneaky",))
    assert [i.name for i in proto.graph.input][:4] == ["features", "style", "content", "target"]
    dims = {i.name: [d.dim_value or d.dim_param for d in i.type.tensor_type.shape.dim] for i in proto.graph.input}
    assert dims["style"][1] == len(added.config.input_styles) and dims["target"][1] == len(added.config.styles)


def test_saved_model_works_where_a_model_is_used(models, tmp_path):
    _, added, meta = models
    stem = tmp_path / "mine"
    ckpt.save_tensors(
        stem,
        ckpt.prefixed("generator", added),
        {
            **meta,
            "config": added.config.to_dict(),
            "added_styles": [{"name": "sneaky", "clips": ["a.bvh"], "frames": 100, "minutes": 1.0}],
        },
    )
    w = load_generator_weights(stem)
    assert w.config.styles[-1] == "sneaky" and w.config.input_styles == ckpt.load_generator()[0].config.styles
    src = tmp_path / "in.bvh"
    bvh.write(src, rig_variants(walk(2.0, fps=30.0))["Blender names and proportions, metres"])
    out = tmp_path / "out.bvh"
    r = subprocess.run(
        [*CLI, "transfer", str(src), "--style", "sneaky", "--model", str(stem), "-o", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    assert bvh.read(out).n_frames == bvh.read(src).n_frames
    r = subprocess.run(
        [
            *CLI,
            "transfer",
            str(src),
            "--mix",
            "sneaky=1,elderly=1",
            "--parts",
            "arms=input",
            "--model",
            str(stem),
            "-o",
            str(tmp_path / "mix.bvh"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    r = subprocess.run([*CLI, "styles", "--model", str(stem)], capture_output=True, text=True, check=False)
    assert "sneaky" in r.stdout and "added:    sneaky (a target only)" in r.stdout, r.stdout
    r = subprocess.run(
        [*CLI, "export-onnx", "--model", str(stem), "--styles", "sneaky", "-o", str(tmp_path / "s.onnx")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    side = json.loads((tmp_path / "s.json").read_text())
    assert side["styles"][-1] == "sneaky" and "sneaky" not in side["input_styles"]
    from styleerd.serve.server import ServeConfig, StyleServer

    assert StyleServer(ServeConfig(model=str(stem))).model.config.styles[-1] == "sneaky"  # styleerd serve --model
    # an input cannot be labelled with a style the model only learned to produce
    with pytest.raises(StyleERDError, match="added to this model as a target only"):
        StreamStylizer(w, "sneaky", "walk", {"elderly": 1.0})
    r = subprocess.run(
        [
            *CLI,
            "transfer",
            str(src),
            "--style",
            "elderly",
            "--input-style",
            "sneaky",
            "--model",
            str(stem),
            "-o",
            str(tmp_path / "x.bvh"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 2 and "unknown --input-style 'sneaky'" in r.stderr and "Traceback" not in r.stderr


def _clip(tmp: Path, name: str = "c.bvh", seconds: float = 2.0) -> str:
    path = tmp / name
    bvh.write(path, walk(seconds, fps=60.0))
    return str(path)


BAD = {
    "no clip": (lambda t: ["add-style", "mine", "-o", str(t / "m")], "the following arguments are required"),
    "bad name": (lambda t: ["add-style", "My Style!", _clip(t), "-o", str(t / "m")], "style name 'My Style!'"),
    "a style it has": (
        lambda t: ["add-style", "elderly", _clip(t), "-o", str(t / "m")],
        "already has a style 'elderly'",
    ),
    "21 clips": (
        lambda t: ["add-style", "mine", *[_clip(t, f"c{i}.bvh") for i in range(21)], "-o", str(t / "m")],
        "from 1 to 20 clips",
    ),
    "clip too short": (
        lambda t: ["add-style", "mine", _clip(t, seconds=0.2), "-o", str(t / "m")],
        "a clip needs at least 24",
    ),
    "clip missing": (lambda t: ["add-style", "mine", str(t / "none.bvh"), "-o", str(t / "m")], "No such file"),
    "unknown content": (
        lambda t: ["add-style", "mine", _clip(t), "--content", "dance", "-o", str(t / "m")],
        "unknown --content 'dance'",
    ),
    "contents do not match the clips": (
        lambda t: [
            "add-style",
            "mine",
            _clip(t),
            _clip(t, "d.bvh"),
            "--content",
            "walk",
            "run",
            "walk",
            "-o",
            str(t / "m"),
        ],
        "one --content for every clip",
    ),
    "like the neutral style": (
        lambda t: ["add-style", "mine", _clip(t), "--like", "normal", "-o", str(t / "m")],
        "--like 'normal' must be one of",
    ),
    "output folder missing": (lambda t: ["add-style", "mine", _clip(t), "-o", str(t / "no" / "m")], "does not exist"),
    "steps 0": (lambda t: ["add-style", "mine", _clip(t), "--steps", "0", "-o", str(t / "m")], "--steps"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_add_style_refuses_bad_requests_in_one_line(case, tmp_path):
    argv, expected = BAD[case]
    r = subprocess.run([*CLI, *argv(tmp_path)], capture_output=True, text=True, timeout=120, check=False)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert expected in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not list(tmp_path.glob("m.*")), "nothing is written"


def test_add_style_trains_from_clips_on_another_skeleton(tmp_path, shared_data):
    """The command end to end, a few steps: clips of a rig with other names, proportions and
    units become a model with one more style; old targets' outputs are unchanged."""
    variants = rig_variants(walk(3.0, fps=60.0))
    clips = []
    for name in ("Blender names and proportions, metres", "joint frames rolled about their bones"):
        clips.append(tmp_path / f"{name.split(',')[0].replace(' ', '-')}.bvh")
        bvh.write(clips[-1], variants[name])
    stem = tmp_path / "mine"
    r = subprocess.run(
        [
            *CLI,
            "add-style",
            "stiff",
            *map(str, clips),
            "--content",
            "walk",
            "--steps",
            "6",
            "--data",
            str(shared_data),
            "-o",
            str(stem),
        ],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert "added stiff from 2 clips" in r.stdout
    w = load_generator_weights(stem)
    assert w.config.styles[-1] == "stiff" and w.config.added_styles == ("stiff",)
    base = load_generator_weights()
    for key, value in base.arrays.items():  # everything the old styles use is the old model's
        if key in ("branch_h0", "branch_c0"):
            np.testing.assert_array_equal(w.arrays[key][: len(value)], value)
        else:
            np.testing.assert_array_equal(w.arrays[key], value, err_msg=key)
    info = w.meta["added_styles"][-1]
    assert info["name"] == "stiff" and info["steps"] == 6 and info["contents"] == ["walk"]
    # its critic read what the shipped recipe's critic read: rotations too (critic_rotations)
    assert base.meta["training"]["config"]["critic_rotations"] and info["critic_reads"] == [
        "rotations",
        "positions",
        "velocities",
    ]


def test_styles_added_one_after_another_keep_each_other(models):
    """A second added style leaves the first one's output (and the trained styles') unchanged."""
    base, added, _ = models
    twice = with_added_style(added, "stomp", "sneaky")
    with torch.no_grad():
        twice.decoder_added[-1].add_(0.05)
    x, style, content = _frames(base, n=20)
    t = np.zeros((3, len(added.config.styles)), np.float32)
    t[:, -1], t[0, 1] = 1.0, 0.5
    before = _run(added, "numba", x, style, content, t)
    after = _run(twice, "numba", x, style, content, np.concatenate([t, np.zeros((3, 1), np.float32)], 1))
    assert np.array_equal(before, after)
    assert twice.config.added_styles == ("sneaky", "stomp") and twice.config.input_styles == base.config.styles
