"""glTF, GLB and VRM input under hostile or careless files (issue 36): every case is one line and
exit 2 from ``transfer``, no traceback, no crash, no hang, nothing written, and nothing read from
outside the input's folder. The corpus is made here from a good file, each case a mutation of its
JSON; a hypothesis fuzzer mutates accessors, buffer views, nodes and animations further and checks
the reader fails only with its own error."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pygltflib as gl
import pytest

from styleerd.errors import StyleERDError
from styleerd.motion.gltf import read_gltf, write_glb
from styleerd.motion.procedural import walk

CLI = [sys.executable, "-m", "styleerd.cli"]


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> gl.GLTF2:
    path = tmp_path_factory.mktemp("good") / "walk.glb"
    write_glb(path, walk(1.0, fps=30.0))
    read_gltf(path)  # the unmutated file reads
    return gl.GLTF2().load_binary(str(path))


def _write_glb(path: Path, document: dict, blob: bytes) -> None:
    """A GLB of a JSON document as it stands (NaN and all: no library in between) and a blob."""
    import struct

    text = json.dumps(document, allow_nan=True).encode()
    text += b" " * (-len(text) % 4)
    blob = blob + b"\0" * (-len(blob) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(blob), b"BIN\0") + blob
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)


def _two_parents(doc: gl.GLTF2) -> None:
    """The first child of the root also a child of the last node."""
    doc.nodes[-1].children = list(doc.nodes[-1].children or []) + [doc.nodes[0].children[0]]


def _rotation_sampler(doc: gl.GLTF2) -> gl.AnimationSampler:
    return doc.animations[0].samplers[0]


def _chain(doc: gl.GLTF2, n: int) -> None:
    """``n`` more nodes in one chain under the root."""
    first = len(doc.nodes)
    doc.nodes += [gl.Node(name=f"extra{k}", children=[first + k + 1] if k < n - 1 else []) for k in range(n)]
    doc.nodes[0].children = list(doc.nodes[0].children or []) + [first]
    doc.skins[0].joints = list(doc.skins[0].joints) + list(range(first, first + n))


def _translation_key(doc: gl.GLTF2, value: float) -> None:
    """The first translation channel's first key value replaced by ``value`` (in the binary blob)."""
    import numpy as np

    anim = doc.animations[0]
    sampler = next(anim.samplers[c.sampler] for c in anim.channels if c.target.path == "translation")
    a = doc.accessors[sampler.output]
    view = doc.bufferViews[a.bufferView]
    blob = bytearray(doc.binary_blob())
    at = (view.byteOffset or 0) + (a.byteOffset or 0)
    blob[at : at + 4] = np.float32(value).tobytes()
    a.max, a.min = None, None
    doc.set_binary_blob(bytes(blob))


def _key_time(doc: gl.GLTF2, value: float) -> None:
    """The time accessor's last key replaced by ``value`` (in the binary blob)."""
    import numpy as np

    a = doc.accessors[_rotation_sampler(doc).input]
    view = doc.bufferViews[a.bufferView]
    blob = bytearray(doc.binary_blob())
    at = (view.byteOffset or 0) + (a.byteOffset or 0) + 4 * (a.count - 1)
    blob[at : at + 4] = np.float32(value).tobytes()
    a.max = None
    doc.set_binary_blob(bytes(blob))


# name -> (mutation of the document, text in the one-line error)
CASES = {
    "negative byteStride": (
        lambda d: setattr(d.bufferViews[d.accessors[_rotation_sampler(d).output].bufferView], "byteStride", -16),
        "byteStride",
    ),
    "byteStride 1e9": (
        lambda d: setattr(d.bufferViews[d.accessors[_rotation_sampler(d).output].bufferView], "byteStride", 10**9),
        "byteStride",
    ),
    "byteStride smaller than an element": (
        lambda d: setattr(d.bufferViews[d.accessors[_rotation_sampler(d).output].bufferView], "byteStride", 4),
        "stride",
    ),
    "negative byteOffset": (
        lambda d: setattr(d.accessors[_rotation_sampler(d).output], "byteOffset", -64),
        "byteOffset",
    ),
    "count past the buffer": (lambda d: setattr(d.accessors[_rotation_sampler(d).output], "count", 10**6), "count"),
    "count past its buffer view": (
        lambda d: setattr(
            d.accessors[_rotation_sampler(d).output], "count", d.accessors[_rotation_sampler(d).output].count + 1
        ),
        "past the end",
    ),
    "count zero": (lambda d: setattr(d.accessors[_rotation_sampler(d).output], "count", 0), "count"),
    "unknown component type": (
        lambda d: setattr(d.accessors[_rotation_sampler(d).output], "componentType", 9999),
        "component type",
    ),
    "unknown accessor type": (
        lambda d: setattr(d.accessors[_rotation_sampler(d).output], "type", "VEC9"),
        "component type",
    ),
    "accessor index out of range": (lambda d: setattr(_rotation_sampler(d), "output", 10**6), "accessor index"),
    "buffer view out of range": (
        lambda d: setattr(d.accessors[_rotation_sampler(d).output], "bufferView", 10**6),
        "bufferView",
    ),
    "sampler index out of range": (lambda d: setattr(d.animations[0].channels[0], "sampler", 10**6), "sampler"),
    "a node its own child": (lambda d: d.nodes[1].children.append(1), "its own child"),
    "a node with two parents": (_two_parents, "a child of both"),
    "a cycle": (
        lambda d: d.nodes[d.nodes[0].children[0]].children.append(0),
        "two parents|a child of both|cycle|deeper",
    ),
    "10,000 nodes deep": (lambda d: _chain(d, 10_000), "deeper than 256"),
    "a child index out of range": (lambda d: d.nodes[0].children.append(10**6), "child"),
    "a skin joint out of range": (lambda d: d.skins[0].joints.append(10**6), "skin joint"),
    "NaN node translation": (lambda d: setattr(d.nodes[1], "translation", [float("nan"), 0.0, 0.0]), "NaN or infinite"),
    "a node 1e30 away": (lambda d: setattr(d.nodes[1], "translation", [1e30, 0.0, 0.0]), "transform is out of range"),
    "a matrix 1e30 away": (
        lambda d: setattr(d.nodes[1], "matrix", [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 1e30, 0, 0, 1.0]),
        "transform is out of range",
    ),
    "a rotation of 1e154": (  # its norm overflowed (a RuntimeWarning printed) before the file was refused
        lambda d: setattr(d.nodes[1], "rotation", [0.0, 0.0, 0.0, 1.3407807929942597e154]),
        "transform is out of range",
    ),
    "a translation key 1e30 away": (lambda d: _translation_key(d, 1e30), "translation is out of range"),
    "a rotation of 3 numbers": (lambda d: setattr(d.nodes[1], "rotation", [0.0, 0.0, 1.0]), "right length"),
    "a zero rotation": (lambda d: setattr(d.nodes[1], "rotation", [0.0, 0.0, 0.0, 0.0]), "rotation is zero"),
    "a zero-scale matrix": (lambda d: setattr(d.nodes[1], "matrix", [0.0] * 16), "zero scale"),
    "key time inf": (lambda d: _key_time(d, float("inf")), "NaN or infinite"),
    "key time 1e7 s": (lambda d: _key_time(d, 1e7), "key times must rise"),
    "key times going back": (lambda d: _key_time(d, -1.0), "key times must rise"),
}


def _refused(args: list, tmp_path: Path, text: str) -> None:
    out = tmp_path / "out.glb"
    done = subprocess.run(
        [*CLI, "transfer", *map(str, args), "--style", "elderly", "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and "Traceback" not in done.stderr, (
        done.returncode,
        done.stderr[-2000:],
    )
    assert any(t in lines[0] for t in text.split("|")), lines[0]
    assert not out.exists() and not list(tmp_path.glob("*.tmp*"))


@pytest.mark.parametrize("case", CASES)
def test_a_malformed_gltf_is_refused_in_one_line(good, tmp_path, case):
    mutate, text = CASES[case]
    doc = copy.deepcopy(good)
    doc.set_binary_blob(good.binary_blob())
    mutate(doc)
    path = tmp_path / "bad.glb"
    _write_glb(path, json.loads(doc.to_json(allow_nan=True)), doc.binary_blob())
    _refused([path], tmp_path, text)


@pytest.mark.parametrize(
    "uri",
    [
        "../secret.bin",
        "/etc/passwd",
        "sub/../../secret.bin",
        "file:///etc/passwd",
        "http://example.com/x.bin",
        "%2e%2e/secret.bin",
    ],
)
def test_a_gltf_buffer_outside_its_folder_is_never_read(good, tmp_path, uri):
    """A .gltf naming a buffer outside its own folder is refused before anything is read (the
    secret beside the folder would otherwise be embedded in the output)."""
    (tmp_path / "secret.bin").write_bytes(b"SECRET" * 1000)
    folder = tmp_path / "in"
    folder.mkdir()
    doc = copy.deepcopy(good)
    doc.buffers = [gl.Buffer(byteLength=len(good.binary_blob()), uri=uri)]
    path = folder / "bad.gltf"
    path.write_text(doc.to_json())
    _refused([path], folder, "outside the file's own folder")


def test_a_gltf_buffer_in_its_own_folder_is_read(good, tmp_path):
    (tmp_path / "walk.bin").write_bytes(good.binary_blob())
    doc = copy.deepcopy(good)
    doc.buffers = [gl.Buffer(byteLength=len(good.binary_blob()), uri="walk.bin")]
    path = tmp_path / "walk.gltf"
    path.write_text(doc.to_json())
    assert read_gltf(path).motion.n_frames == 30


@pytest.mark.parametrize("examples", [150, pytest.param(3000, marks=pytest.mark.slow, id="long")])
def test_fuzzed_gltf_documents_read_or_fail_with_the_readers_own_error(good, tmp_path, examples):
    """Structured fuzzing of the JSON: any field of accessors, buffer views, nodes, skins, samplers
    and channels set to any JSON value; the reader reads the file or raises StyleERDError. The long
    run (3,000 documents) is marked slow; CI runs it."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    values = (
        st.none()
        | st.booleans()
        | st.integers(-(2**40), 2**40)
        | st.floats(allow_nan=True, allow_infinity=True)
        | st.text(max_size=4)
        | st.lists(st.integers(-3, 40) | st.floats(allow_nan=True), max_size=5)
    )
    fields = st.sampled_from(
        [("accessors", k) for k in ("bufferView", "byteOffset", "componentType", "count", "type", "normalized")]
        + [("bufferViews", k) for k in ("byteOffset", "byteLength", "byteStride", "buffer")]
        + [("nodes", k) for k in ("children", "translation", "rotation", "scale", "matrix")]
        + [("skins", "joints")]
    )
    base = json.loads(good.to_json())
    blob = good.binary_blob()
    path = tmp_path / "fuzz.glb"

    @settings(max_examples=examples, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
    @given(st.lists(st.tuples(fields, st.integers(0, 40), values), min_size=1, max_size=3))
    def run(changes):
        d = copy.deepcopy(base)
        for (what, key), k, value in changes:
            items = d.get(what) or []
            if items:
                items[k % len(items)][key] = value
        _write_glb(path, d, blob)
        try:
            read_gltf(path)
        except StyleERDError as e:
            assert str(e) and "\n" not in str(e).strip()

    run()
