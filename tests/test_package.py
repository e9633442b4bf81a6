"""styleerd as users install it: a wheel built from this checkout, installed into a fresh
virtualenv outside it without torch, runs transfer, export and the server (viewer page and its
vendored three.js answer); the README's Python API example runs as written."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import run_checked as _run

from styleerd.motion import bvh, procedural

ROOT = Path(__file__).resolve().parents[1]


def python_example(doc: str, section: str) -> str:
    """The first ```python block of ``section`` in ``doc``."""
    text = ROOT.joinpath(doc).read_text().split(f"\n## {section}\n", 1)[-1]
    return re.search(r"```python\n(.*?)```", text, re.DOTALL).group(1)


@pytest.mark.parametrize(("doc", "section"), [("README.md", "Python API"), ("docs/guide/python.md", "Python API")])
def test_python_examples_run_as_written(tmp_path, doc, section):
    code = python_example(doc, section) + "\nprint('torch loaded' if 'torch' in sys.modules else 'no torch needed')\n"
    (tmp_path / "example.py").write_text("import sys\n" + code)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "example.py"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600, check=False
    )
    assert done.returncode == 0, done.stderr
    assert "no torch needed" in done.stdout
    out = bvh.read(tmp_path / "walk-elderly.bvh")
    source = bvh.read(tmp_path / "walk.bvh")
    assert out.n_frames == source.n_frames and out.skeleton.names == source.skeleton.names
    assert np.degrees(np.abs(out.rotations - source.rotations)).max() > 1.0  # stylised, not copied


def readme_commands() -> list[str]:
    """Every ``styleerd`` command line in the README's shell blocks, comments removed."""
    blocks = re.findall(r"```\n(.*?)```", ROOT.joinpath("README.md").read_text(), re.DOTALL)
    lines = [line.split("  #")[0].strip() for block in blocks for line in block.splitlines()]
    return [line for line in lines if line.startswith("styleerd ")]


def test_every_readme_command_is_one_the_cli_takes_and_the_first_runs(tmp_path):
    from styleerd.cli import build_parser

    commands = readme_commands()
    assert len(commands) >= 6 and ROOT.joinpath("README.md").read_text().count("\nmake demo\nmake test\n") == 1
    parser = build_parser()
    for command in commands:
        args = parser.parse_args(shlex.split(command)[1:])  # argparse exits on a command it does not take
        assert args.func is not None, command
    bvh.write(tmp_path / "walk.bvh", procedural.walk(seconds=2))
    first = shlex.split(commands[0])
    assert first[:3] == ["styleerd", "transfer", "walk.bvh"], first
    _run([sys.executable, "-m", "styleerd.cli", *first[1:]], cwd=tmp_path)
    assert bvh.read(tmp_path / first[-1]).n_frames == bvh.read(tmp_path / "walk.bvh").n_frames


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_wheel_carries_the_models_and_the_viewer(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for stem in ("styleerd-bandai2", "labeller-bandai2", "recognisers-bandai2", "fmd-bandai2"):
        assert {f"styleerd/models/{stem}.safetensors", f"styleerd/models/{stem}.json"} <= names
    assert {
        "styleerd/serve/static/index.html",
        "styleerd/serve/static/vendor/three.module.js",
        "styleerd/serve/static/vendor/three.core.js",
        "styleerd/serve/static/engine.html",
        "styleerd/serve/static/vendor/ort.wasm.min.mjs",
        "styleerd/serve/static/vendor/ort-wasm-simd-threaded.wasm",
        "styleerd/serve/static/vendor/three-vrm.module.js",
        "styleerd/serve/static/vendor/loaders/GLTFLoader.js",
        "styleerd/serve/static/vendor/utils/BufferGeometryUtils.js",
        "styleerd/serve/static/vendor/utils/SkeletonUtils.js",
    } <= names
    assert not any(n.startswith(("tests/", "models/ablations", "benchmarks/")) for n in names)
    metadata = next(zipfile.ZipFile(wheel).read(n).decode() for n in names if n.endswith("METADATA"))
    requires = [line for line in metadata.splitlines() if line.startswith("Requires-Dist:") and "extra ==" not in line]
    assert requires and not any("torch" in line or "matplotlib" in line for line in requires)


@pytest.fixture(scope="module")
def light_install(wheel, tmp_path_factory) -> Path:
    """A fresh virtualenv outside the checkout with the wheel and its light dependencies."""
    venv = tmp_path_factory.mktemp("light") / "venv"
    _run([sys.executable, "-m", "venv", venv])
    _run([venv / "bin/python", "-m", "pip", "install", "--quiet", wheel])
    return venv


def test_light_install_runs_transfer_export_and_api_without_torch(light_install, tmp_path):
    python, cli = light_install / "bin/python", light_install / "bin/styleerd"
    bvh.write(tmp_path / "walk.bvh", procedural.walk(seconds=3.0))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    missing = subprocess.run([python, "-c", "import torch"], capture_output=True, cwd=tmp_path, env=env, check=False)
    assert missing.returncode != 0  # torch is not part of the light install
    styles = _run([cli, "styles"], cwd=tmp_path, env=env).stdout
    assert "elderly" in styles and "CC BY-NC 4.0" in styles
    _run([cli, "transfer", "walk.bvh", "--style", "elderly", "-o", "out.bvh"], cwd=tmp_path, env=env)
    assert bvh.read(tmp_path / "out.bvh").n_frames == bvh.read(tmp_path / "walk.bvh").n_frames
    _run(
        [cli, "transfer", "walk.bvh", "--style", "elderly", "--backend", "numba", "-o", "out-numba.bvh"],
        cwd=tmp_path,
        env=env,
    )
    a, b = bvh.read(tmp_path / "out.bvh"), bvh.read(tmp_path / "out-numba.bvh")
    assert np.abs(a.rotations - b.rotations).max() < 1e-4  # the fast backend, the same output
    for backend in ("torch", "onnx"):  # not in the light install: one line saying what to install
        done = subprocess.run(
            [cli, "transfer", "walk.bvh", "--style", "elderly", "--backend", backend, "-o", "x.bvh"],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
        assert done.returncode == 2 and "styleerd[train]" in done.stderr and "Traceback" not in done.stderr, done.stderr
    _run([cli, "export-onnx", "-o", "step.onnx"], cwd=tmp_path, env=env)
    assert json.loads((tmp_path / "step.json").read_text())["styles"]
    api = (
        "import styleerd, sys; m = styleerd.load(); print(styleerd.transfer('walk.bvh', 'feminine').n_frames, "
        "'torch' in sys.modules, styleerd.__file__)"
    )
    frames, torch_loaded, where = _run([python, "-c", api], cwd=tmp_path, env=env).stdout.split()
    assert frames == str(bvh.read(tmp_path / "walk.bvh").n_frames) and torch_loaded == "False"
    assert Path(where).is_relative_to(light_install) and not Path(where).is_relative_to(ROOT)


@contextlib.contextmanager
def _served_viewer(cli: Path, cwd: Path, env: dict):
    """``styleerd serve`` of the install ``cli`` on a free port; yields (port, the viewer page's HTML)."""
    port = _free_port()
    server = subprocess.Popen(
        [cli, "serve", "--port", str(port)], cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    try:
        deadline, page = time.monotonic() + 300, None  # the first start compiles the numba engine
        while page is None:
            try:
                page = urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5).read().decode()
            except OSError:
                assert server.poll() is None and time.monotonic() < deadline, (
                    server.stdout.read().decode() if server.poll() is not None else "no answer"
                )
                time.sleep(0.5)
        yield port, page
    finally:
        server.terminate()
        server.wait(30)


def _vendored(port: int, name: str) -> bytes:
    return urllib.request.urlopen(f"http://127.0.0.1:{port}/static/vendor/{name}", timeout=5).read()


def test_light_install_serves_the_viewer(light_install, tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    with _served_viewer(light_install / "bin/styleerd", tmp_path, env) as (port, page):
        assert "<canvas" in page or "viewer.js" in page
        assert len(_vendored(port, "three.module.js")) > 100_000
        for name in ("three-vrm.module.js", "loaders/GLTFLoader.js"):  # the avatar viewer's
            assert len(_vendored(port, name)) > 10_000


def test_help_groups_every_command_and_transfer_help_lists_the_styles():
    from styleerd.cli import GROUPS, build_parser
    from styleerd.model.stored import load_generator_weights

    parser = build_parser()
    commands = set(next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices)
    grouped = [name for names in GROUPS.values() for name in names]
    assert sorted(grouped) == sorted(commands) and len(grouped) == len(set(grouped))
    top = parser.format_help()
    assert all(f"{group}:" in top for group in GROUPS) and "CC BY-NC 4.0" in top
    transfer = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "transfer", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    ).stdout
    assert all(style in transfer for style in load_generator_weights().config.styles)


def test_models_are_found_by_path_by_name_in_styleerd_models_and_shipped(tmp_path):
    from styleerd.models import MODELS_DIR

    mine = tmp_path / "mine"
    mine.mkdir()
    for suffix in (".safetensors", ".json"):
        (mine / f"my-model{suffix}").write_bytes((MODELS_DIR / f"styleerd-bandai2{suffix}").read_bytes())
    env = {**os.environ, "STYLEERD_MODELS": f"{tmp_path / 'nothing-here'}{os.pathsep}{mine}"}
    for name in ("my-model", str(mine / "my-model"), str(mine / "my-model.safetensors")):
        done = subprocess.run(
            [sys.executable, "-m", "styleerd.cli", "styles", "--model", name],
            capture_output=True,
            text=True,
            timeout=60,
            env=env,
            check=False,
        )
        assert done.returncode == 0 and f"model:    {mine / 'my-model.safetensors'}" in done.stdout, done.stderr
    shipped = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "styles"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        check=False,
    )
    assert (
        f"model:    {MODELS_DIR / 'styleerd-bandai2.safetensors'}" in shipped.stdout.splitlines()[0]
    )  # the default first
    for generator in MODELS_DIR.glob("styleerd-*.safetensors"):  # then every other shipped model
        assert f"model:    {generator}" in shipped.stdout
    # each with the range its identity pass keeps the network's pose in (``styleerd familiar``)
    assert "within 10 deg of the input, the input's from 16 deg (measured" in shipped.stdout
    assert "within 7 deg of the input, the input's from 13 deg (measured" in shipped.stdout
    missing = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "styles", "--model", "nope"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        check=False,
    )
    assert missing.returncode == 2 and "cannot load model nope.safetensors" in missing.stderr


def test_the_docs_name_only_styles_the_model_has():
    from styleerd.model.stored import load_generator_weights

    styles = set(load_generator_weights().config.styles)
    docs = ["README.md", "docs/PROTOCOL.md", "docs/ONNX.md", *map(str, sorted(ROOT.glob("docs/guide/*.md")))]
    for doc in docs:
        text = "\n".join(line for line in ROOT.joinpath(doc).read_text().splitlines() if "--model" not in line)
        named = set(re.findall(r'"style": "([a-z-]+)"', text)) | set(re.findall(r"--style ([a-z-]+)", text))
        named |= set(re.findall(r'\.(?:stylizer|transfer|set_style)\([^)]*?"([a-z-]+)"', text)) - {"walk.bvh"}
        mixes = re.findall(r"--mix ([a-z=0-9.,-]+)", text)
        named |= {name for pair in mixes for name in re.findall(r"([a-z-]+)=", pair)}
        assert named <= styles, f"{doc} names styles the model does not have: {named - styles}"
    for style in styles:
        assert ROOT.joinpath("docs/styles", f"{style}.png").is_file()
        for doc in ("README.md", "docs/guide/transfer.md"):
            assert f"styles/{style}.png" in ROOT.joinpath(doc).read_text(), (doc, style)
    transfer = ROOT.joinpath("docs/guide/transfer.md").read_text()
    assert "numba" in transfer.split("[--backend ", 1)[1].split("]", 1)[0]


def test_a_model_finds_the_labeller_of_its_labels(tmp_path, monkeypatch):
    """Each model's labels are inferred by the labeller trained on the same labels (a model
    added styles to keeps its base's labeller: added styles are targets only)."""
    from dataclasses import replace

    from styleerd.model.stored import labeller_stem, load_generator_weights
    from styleerd.models import MODELS_DIR

    config = load_generator_weights().config
    assert labeller_stem(config) == MODELS_DIR / "labeller-bandai2"
    assert (
        labeller_stem(replace(config, styles=(*config.styles, "sneaky"), added_styles=("sneaky",)))
        == MODELS_DIR / "labeller-bandai2"
    )
    other = replace(config, styles=("calm", "normal"), added_styles=())
    meta = json.loads((MODELS_DIR / "labeller-bandai2.json").read_text())
    (tmp_path / "labeller-calm.json").write_text(json.dumps({**meta, "styles": ["calm", "normal"]}))
    monkeypatch.setenv("STYLEERD_MODELS", str(tmp_path))
    assert labeller_stem(other) == tmp_path / "labeller-calm"


@pytest.mark.skipif(not shutil.which("npm") or not shutil.which("make"), reason="npm or make missing")
def test_a_fresh_clone_serves_the_avatar_viewer_right_after_make_demo(tmp_path):
    """``git clone`` then ``make demo`` (a new .venv, the install, the demo) and ``styleerd serve``
    shows its viewer, three.js and three-vrm included: nothing else to run first."""
    clone = tmp_path / "clone"
    _run(["git", "clone", "--quiet", ROOT, clone])
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    _run(["make", "demo"], cwd=clone, env=env)
    with _served_viewer(clone / ".venv/bin/styleerd", tmp_path, env) as (port, page):
        assert 'id="avatar"' in page
        for name in ("three.module.js", "three-vrm.module.js", "loaders/GLTFLoader.js"):
            assert len(_vendored(port, name)) > 10_000
