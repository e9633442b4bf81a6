"""The command line under hostile or careless input: every case is one line on stderr, exit 2
(141, silently, for a reader that left), no traceback, and nothing written. The corpus is made
by the tests themselves, so it stays with the project; a hypothesis fuzzer mutates a good file
and checks the reader never fails any other way."""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from safetensors.numpy import save_file
from test_bvh import GOOD

from styleerd.errors import StyleERDError
from styleerd.model.checkpoint import load_generator
from styleerd.models import MODELS_DIR
from styleerd.motion import bvh
from styleerd.motion.procedural import walk
from styleerd.runtime.stylizer import parse_mix, target_weights

CLI = [sys.executable, "-m", "styleerd.cli"]


def _walk_file(path: Path, n_seconds: float = 1.0) -> Path:
    bvh.write(path, walk(n_seconds, fps=30.0))
    return path


def _header_variant(path: Path, old: str, new: str) -> Path:
    path.write_text(GOOD.replace(old, new))
    return path


def _deep(path: Path, depth: int = 1200) -> Path:
    lines = [
        "HIERARCHY",
        "ROOT J0",
        "{",
        "OFFSET 0 0 0",
        "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
    ]
    for d in range(1, depth):
        lines += [f"JOINT J{d}", "{", "OFFSET 0 1 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
    lines += ["}"] * depth + ["MOTION", "Frames: 0", "Frame Time: 0.0333333"]
    path.write_text("\n".join(lines) + "\n")
    return path


def _zero_offsets(path: Path) -> Path:
    m = walk(1.0, fps=30.0)
    sk = m.skeleton
    flat = type(sk)(
        sk.names, sk.parents, np.zeros_like(sk.offsets), sk.channels, tuple((j, np.zeros(3)) for j, _ in sk.end_sites)
    )
    text = bvh.format_header(flat, m.n_frames, 30.0) + bvh.format_frames(bvh.channel_values(m))
    path.write_text(text)
    return path


def _absurd_root(path: Path) -> Path:
    m = walk(2.0, fps=30.0)
    values = bvh.channel_values(m)
    values[12, 0] = 1e30  # one root X: was stylised, changing 62 output frames
    path.write_text(bvh.format_header(m.skeleton, m.n_frames, 30.0) + bvh.format_frames(values))
    return path


def _truncated_model(tmp: Path) -> str:
    data = (MODELS_DIR / "styleerd-bandai2.safetensors").read_bytes()
    (tmp / "cut.safetensors").write_bytes(data[: len(data) // 2])
    return str(tmp / "cut")


def _model_without_config(tmp: Path) -> str:
    save_file({"w": np.zeros(3, np.float32)}, str(tmp / "bare.safetensors"))
    return str(tmp / "bare")


def _labeller_as_generator(tmp: Path) -> str:
    for suffix in (".safetensors", ".json"):
        (tmp / f"lab{suffix}").write_bytes((MODELS_DIR / f"labeller-bandai2{suffix}").read_bytes())
    return str(tmp / "lab")


def _model_with_posture_offsets(tmp: Path, offsets: dict, frame: object = "body") -> str:
    """The shipped model with its posture's joint offsets replaced by ``offsets`` (style -> rows),
    said to be in ``frame``."""
    import json

    from styleerd.model.stored import load_arrays

    arrays, meta = load_arrays(MODELS_DIR / "styleerd-bandai2")
    meta["posture"]["offsets"], meta["posture"]["frame"] = offsets, frame
    save_file(arrays, str(tmp / "bent.safetensors"), metadata={"styleerd": json.dumps(meta)})
    return str(tmp / "bent")


def _model_with_familiar(tmp: Path, familiar: object) -> str:
    """The shipped model with its measured familiar range replaced by ``familiar``."""
    import json

    from styleerd.model.stored import load_arrays

    arrays, meta = load_arrays(MODELS_DIR / "styleerd-bandai2")
    meta["familiar"] = familiar
    save_file(arrays, str(tmp / "odd.safetensors"), metadata={"styleerd": json.dumps(meta)})
    return str(tmp / "odd")


def _transfer(make_input, *extra: str, output: str = "out.bvh"):
    def argv(tmp: Path) -> list[str]:
        source = make_input(tmp)
        out = output.replace("{in}", str(source)).replace("{tmp}", str(tmp))
        target = [] if "--mix" in extra else ["--style", "elderly"]  # a mixture is the target instead
        return ["transfer", str(source), *target, "-o", out if out.startswith("/") else str(tmp / out), *extra]

    return argv


def _walk(tmp: Path) -> Path:
    return _walk_file(tmp / "in.bvh")


# name -> (argv from a scratch folder, text the one error line must contain)
CASES = {
    "Frames: nan": (
        lambda t: ["info", str(_header_variant(t / "in.bvh", "Frames: 2", "Frames: nan"))],
        "is not a frame count",
    ),
    "Frames: inf": (
        lambda t: ["info", str(_header_variant(t / "in.bvh", "Frames: 2", "Frames: inf"))],
        "is not a frame count",
    ),
    "Frames: 1e400": (
        lambda t: ["info", str(_header_variant(t / "in.bvh", "Frames: 2", "Frames: 1e400"))],
        "is not a frame count",
    ),
    "Frames: -3": (
        lambda t: ["info", str(_header_variant(t / "in.bvh", "Frames: 2", "Frames: -3"))],
        "is not a frame count",
    ),
    "Frame Time: 0": (
        lambda t: ["info", str(_header_variant(t / "in.bvh", "Frame Time: 0.0333333", "Frame Time: 0"))],
        "must be a positive number",
    ),
    "Frame Time: nan": (
        lambda t: ["info", str(_header_variant(t / "in.bvh", "Frame Time: 0.0333333", "Frame Time: nan"))],
        "must be a positive number",
    ),
    "1,200 joints deep": (lambda t: ["info", str(_deep(t / "in.bvh"))], "at most 256 are supported"),
    "deep hierarchy into transfer": (_transfer(lambda t: _deep(t / "in.bvh")), "at most 256 are supported"),
    "one endless line (/dev/zero)": (lambda t: ["info", "/dev/zero"], "line longer than"),
    "/dev/zero into transfer": (
        lambda t: ["transfer", "/dev/zero", "--style", "elderly", "-o", str(t / "out.bvh")],
        "line longer than",
    ),
    "empty file": (lambda t: ["info", str(_touch(t / "in.bvh"))], "it is empty"),
    "binary file": (lambda t: ["info", str(_bytes(t / "in.bvh", b"\x89PNG\r\n\x1a\n\xff\xfe"))], "not a text file"),
    "a folder with no motion in it": (lambda t: ["info", str(t)], "no motion files (.bvh, .glb"),
    "input missing": (lambda t: ["info", str(t / "nope.bvh")], "No such file"),
    "all offsets zero": (_transfer(lambda t: _zero_offsets(t / "in.bvh")), "no length"),
    "root X of 1e30": (
        _transfer(lambda t: _absurd_root(t / "in.bvh")),
        "frame 12: joint 'Hips' Xposition = 1e+30 is out of range",
    ),
    "output folder missing": (_transfer(_walk, output="{tmp}/no/such/out.bvh"), "does not exist"),
    "output is the input's folder": (
        _transfer(_walk, output="{tmp}"),
        "the output is the input file",
    ),  # a folder takes the input's name
    "output not writable": (_transfer(_walk, output="/proc/out.bvh"), "/proc/out.bvh"),
    "output is the input": (_transfer(_walk, output="{in}"), "the output is the input file"),
    "resample onto its input": (
        lambda t: ["resample", str(_walk(t)), "--fps", "60", "-o", str(t / "in.bvh")],
        "the output is the input file",
    ),
    "output .txt": (_transfer(_walk, output="out.txt"), "the output must be .bvh, .glb, .vrma or .fbx"),
    "BVH to .vrm": (_transfer(_walk, output="out.vrm"), "a .vrm is a character: put the motion on one with --onto"),
    "--content with a typo": (_transfer(_walk, "--content", "wlak"), "unknown --content 'wlak' (did you mean 'walk'?)"),
    "--style with a capital": (
        lambda t: ["transfer", str(_walk(t)), "--style", "Elderly", "-o", str(t / "o.bvh")],
        "unknown style 'Elderly' (did you mean 'elderly'?); valid: active, elderly",
    ),
    "--style and --mix": (
        _transfer(_walk, "--mix", "feminine=1", "--style", "elderly"),
        "give --style or --mix, not both",
    ),
    "--to for one file": (_transfer(_walk, "--to", "glb"), "--to glb names the kind of files written into a folder"),
    "--mesh into a BVH": (_transfer(_walk, "--mesh"), "changes nothing in this transfer: --mesh"),
    "--animation of a BVH": (_transfer(_walk, "--animation", "Walk"), "--animation: picks an animation of a glTF"),
    "--keep-original from a BVH": (
        _transfer(_walk, "--keep-original", output="out.glb"),
        "--keep-original: keeps a glTF/VRM or FBX file's own animations",
    ),
    "truncated model": (lambda t: ["styles", "--model", _truncated_model(t)], "cannot load model"),
    "model without its config": (
        lambda t: ["styles", "--model", _model_without_config(t)],
        "no styleerd configuration",
    ),
    "labeller given as the model": (lambda t: ["styles", "--model", _labeller_as_generator(t)], "incomplete"),
    "posture offsets not finite": (
        lambda t: ["styles", "--model", _model_with_posture_offsets(t, {"elderly": [[float("nan")] * 3] * 21})],
        "posture: offsets must be finite and at most 1e6",
    ),
    "posture offsets of 1e30": (
        lambda t: ["styles", "--model", _model_with_posture_offsets(t, {"elderly": [[1e30, 0.0, 0.0]] * 21})],
        "posture: offsets must be finite and at most 1e6",
    ),
    "posture offsets of a style the model lacks": (
        lambda t: ["styles", "--model", _model_with_posture_offsets(t, {"zombie": [[0.0] * 3] * 21})],
        "posture offsets of 'zombie', a style the model does not have",
    ),
    "familiar range upside down": (
        lambda t: ["styles", "--model", _model_with_familiar(t, {"degrees": [16, 10]})],
        "familiar degrees [16, 10]: give two angles, 0 <= the first < the second <= 180",
    ),
    "familiar range not a number": (
        lambda t: ["styles", "--model", _model_with_familiar(t, {"degrees": ["NaN", 5]})],
        "familiar degrees ['NaN', 5]: give two angles",
    ),
    "familiar range of three angles": (
        lambda t: ["styles", "--model", _model_with_familiar(t, {"degrees": [1, 2, 3]})],
        "familiar degrees [1, 2, 3]: give two angles",
    ),
    "familiar range a string": (
        lambda t: ["styles", "--model", _model_with_familiar(t, "10-16")],
        "familiar degrees 10-16: give two angles",
    ),
    "posture offsets in a frame there is none of": (
        lambda t: ["styles", "--model", _model_with_posture_offsets(t, {"elderly": [[0.0] * 3] * 21}, ["body"])],
        "posture frame ['body']; valid: heading, body",
    ),
    "posture offsets of the wrong shape": (
        lambda t: ["styles", "--model", _model_with_posture_offsets(t, {"elderly": [[0.0, 1.0]]})],
        "could not broadcast",
    ),
    "model missing": (
        lambda t: ["transfer", str(_walk(t)), "--style", "elderly", "--model", str(t / "none"), "-o", str(t / "o.bvh")],
        "No such file",
    ),
    "--mix weight nan": (_transfer(_walk, "--mix", "elderly=nan"), "mixture weights must be finite"),
    "--mix weight inf": (_transfer(_walk, "--mix", "elderly=inf,feminine=1"), "mixture weights must be finite"),
    "--mix negative": (_transfer(_walk, "--mix", "elderly=-1,feminine=2"), "mixture weights must be finite"),
    "--mix not a mixture": (_transfer(_walk, "--mix", "elderly"), "mix 'elderly': expected STYLE=WEIGHT"),
    "--mix unknown style": (_transfer(_walk, "--mix", "zombie=1"), "unknown style 'zombie'"),
    "--intensity nan": (_transfer(_walk, "--intensity", "nan"), "intensity nan is outside"),
    "--intensity 3": (_transfer(_walk, "--intensity", "3"), "intensity 3 is outside"),
    "--parts unknown part": (_transfer(_walk, "--parts", "tail=elderly"), "unknown body part 'tail'"),
    "--parts no target": (_transfer(_walk, "--parts", "legs"), "give part=style"),
    "--parts unknown style": (_transfer(_walk, "--parts", "legs=zombie"), "unknown style 'zombie'"),
    "--parts intensity nan": (_transfer(_walk, "--parts", "legs=elderly:nan"), "intensity nan is outside"),
    "--parts intensity text": (_transfer(_walk, "--parts", "arms=elderly:high"), "intensity 'high' is not a number"),
    "--input-style unknown": (_transfer(_walk, "--input-style", "zombie"), "unknown --input-style 'zombie'; valid"),
    "--joint-map missing": (_transfer(_walk, "--joint-map", "/nonexistent.json"), "--joint-map /nonexistent.json"),
    "--joint-map not an object": (
        lambda t: [
            "transfer",
            str(_walk(t)),
            "--style",
            "elderly",
            "--joint-map",
            str(_bytes(t / "m.json", b"[1, 2]")),
            "-o",
            str(t / "o.bvh"),
        ],
        "expected a JSON object",
    ),
    "--joint-map to a missing joint": (
        lambda t: [
            "transfer",
            str(_walk(t)),
            "--style",
            "elderly",
            "--joint-map",
            str(_bytes(t / "m.json", b'{"Hips": "Nope"}')),
            "-o",
            str(t / "o.bvh"),
        ],
        "Nope",
    ),
    "resample --fps nan": (
        lambda t: ["resample", str(_walk(t)), "--fps", "nan", "-o", str(t / "o.bvh")],
        "outside [1, 1000]",
    ),
    "resample a glTF": (
        lambda t: ["resample", str(_touch(t / "in.vrma")), "--fps", "30", "-o", str(t / "o.bvh")],
        "resample changes a BVH file's frame rate",
    ),
    "resample --fps 0": (
        lambda t: ["resample", str(_walk(t)), "--fps", "0", "-o", str(t / "o.bvh")],
        "outside [1, 1000]",
    ),
    "serve --port 70000": (lambda t: ["serve", "--port", "70000"], "a port number is 0..65535"),
    "serve --workers 0": (lambda t: ["serve", "--workers", "0"], "at least 1"),
    "serve --queue -5": (lambda t: ["serve", "--queue", "-5"], "at least 1"),
    "serve --max-message 10": (lambda t: ["serve", "--max-message", "10"], "at least 1024"),
    "serve --id with a dot": (lambda t: ["serve", "--id", "s0.evil"], "a server's name is 1 to 40 letters"),
    "serve --id empty": (lambda t: ["serve", "--id", ""], "a server's name is 1 to 40 letters"),
    "serve --threads 0": (lambda t: ["serve", "--threads", "0"], "at least 1"),
    "serve --loop trio": (lambda t: ["serve", "--loop", "trio"], "invalid choice"),
    "load-test --streams-per-client 0": (lambda t: ["load-test", "--streams-per-client", "0"], "at least 1"),
    "load-test --clients 0": (lambda t: ["load-test", "--clients", "0"], "at least 1"),
    "load-test --seconds nan": (lambda t: ["load-test", "--seconds", "nan"], "a positive number"),
    "bench --steps 0": (lambda t: ["bench", "--steps", "0"], "at least 1"),
    "vmc --fps inf": (lambda t: ["vmc", "--fps", "inf"], "a positive number"),
    "stream-bvh to nowhere": (
        lambda t: ["stream-bvh", str(_walk(t)), "--style", "elderly", "--to", "ws://127.0.0.1:9/"],
        "cannot connect",
    ),
    "stream-bvh -o onto its input": (
        lambda t: ["stream-bvh", str(_walk(t)), "--style", "elderly", "-o", str(t / "in.bvh")],
        "the output is the input file",
    ),
    "export-onnx into a missing folder": (lambda t: ["export-onnx", "-o", str(t / "no" / "m.onnx")], "does not exist"),
}


def _touch(path: Path) -> Path:
    path.write_text("")
    return path


def _bytes(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _run(argv: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run(CLI + argv, capture_output=True, text=True, timeout=120, check=False, **kw)


@pytest.mark.parametrize("case", CASES)
def test_bad_input_is_one_line_exit_2_and_nothing_written(case, tmp_path):
    argv = CASES[case][0](tmp_path)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    r = _run(argv)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert CASES[case][1] in lines[0] and lines[0].startswith("styleerd"), r.stderr
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # no output, no temporary file


def test_a_file_size_limit_is_one_line_and_leaves_nothing(tmp_path):
    """A full disk or a file-size limit (EFBIG) in the middle of writing."""
    source = _walk_file(tmp_path / "in.bvh", 20.0)

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    r = subprocess.run(
        CLI + ["transfer", str(source), "--style", "elderly", "-o", str(tmp_path / "out.bvh")],
        capture_output=True,
        text=True,
        preexec_fn=limit,
        timeout=120,
        check=False,
    )
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [r.stderr.strip()] and "File too large" in r.stderr, (
        r.stderr
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.bvh"]


def test_a_reader_that_leaves_ends_the_command_quietly(tmp_path):
    """`styleerd info FILE | head -1`: the pipe is closed before the command writes."""
    source = _walk_file(tmp_path / "in.bvh")
    p = subprocess.Popen(CLI + ["info", str(source)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(60) == 141 and err == "", err


def test_a_temporary_file_of_a_killed_writer_is_removed_by_the_next_write(tmp_path):
    """kill -9 during a checkpoint write leaves its temporary file; the next write of the same
    file removes it (a live writer's is left alone)."""
    script = (
        "import sys, time; from styleerd.atomic import atomic_write; atomic_write(sys.argv[1], lambda tmp: "
        "(open(tmp, 'w').write('half'), print('writing', flush=True), time.sleep(60)))"
    )
    p = subprocess.Popen(
        [sys.executable, "-c", script, str(tmp_path / "best.safetensors")], stdout=subprocess.PIPE, text=True
    )
    assert p.stdout.readline().strip() == "writing"
    left = [q.name for q in tmp_path.iterdir()]
    assert len(left) == 1 and left[0].startswith(".best.safetensors.") and left[0].endswith(".tmp")
    p.kill()
    p.wait()
    assert [q.name for q in tmp_path.iterdir()] == left  # the orphan
    from styleerd.atomic import atomic_write_text

    atomic_write_text(tmp_path / "best.safetensors", "whole")
    assert [q.name for q in tmp_path.iterdir()] == ["best.safetensors"]


def test_huge_mixture_weights_keep_their_proportions():
    model, _ = load_generator()
    assert target_weights(model, mix={"elderly": 1e308, "feminine": 1e308}) == {"elderly": 0.5, "feminine": 0.5}
    for bad in ({"elderly": float("nan")}, {"elderly": 0.0}, {"elderly": True}):
        with pytest.raises(StyleERDError, match="mixture weights"):
            target_weights(model, mix=bad)
    with pytest.raises(StyleERDError, match="give a style or a mixture, not both"):  # the API, server, VMC bridge
        target_weights(model, "elderly", mix={"feminine": 1.0})
    assert target_weights(model, "elderly", mix={}) == {"elderly": 1.0}  # an empty mixture is none


def test_a_written_mixture_is_read_or_refused_naming_it():
    """``parse_mix``: what ``--mix``, stream-bvh, the VMC bridge and the Blender add-on's field read."""
    assert parse_mix(" elderly=0.5, feminine=1.5 ") == {"elderly": 0.5, "feminine": 1.5}
    assert parse_mix("  ") is None
    for bad in ("elderly", "elderly=", "elderly=0.5=1", "elderly=half", ",", "=1"):
        with pytest.raises(StyleERDError, match="expected STYLE=WEIGHT") as err:
            parse_mix(bad)
        assert repr(bad) in str(err.value)


def test_a_motion_of_all_zero_channels_on_the_models_skeleton_is_stylised(tmp_path):
    """Every joint at one point (no bone has length): foot cleanup once produced NaN here."""
    model, _ = load_generator()
    sk = model.skeleton
    (tmp_path / "z.bvh").write_text(
        bvh.format_header(sk, 40, 30.0) + bvh.format_frames(np.zeros((40, sum(map(len, sk.channels)))))
    )
    r = _run(
        [
            "transfer",
            str(tmp_path / "z.bvh"),
            "--style",
            "elderly",
            "--input-style",
            "normal",
            "--content",
            "walk",
            "-o",
            str(tmp_path / "o.bvh"),
        ]
    )
    assert r.returncode == 0, r.stderr
    assert np.isfinite(bvh.channel_values(bvh.read(tmp_path / "o.bvh"))).all()


def test_info_reads_a_long_file_in_bounded_memory(tmp_path, capsys):
    """`info` streams: its peak memory does not grow with the file (was: the whole text)."""
    import tracemalloc

    from styleerd.cli import main

    peaks = []
    for seconds in (60.0, 600.0):  # both longer than the reader's chunk of 1,024 frames
        source = _walk_file(tmp_path / f"w{int(seconds)}.bvh", seconds)
        tracemalloc.start()
        assert main(["info", str(source)]) == 0
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert "18000 frames" in capsys.readouterr().out
    assert peaks[1] < 1.5 * peaks[0], peaks  # 10x the frames, about the same memory (lines grow a little longer)


# ---- the reader, fuzzed: any mutation of a good file is read or refused with a BVHError

_TOKENS = [
    "{",
    "}",
    "JOINT",
    "ROOT",
    "End",
    "Site",
    "OFFSET",
    "CHANNELS",
    "MOTION",
    "Frames:",
    "Frame",
    "Time:",
    "nan",
    "inf",
    "-inf",
    "1e400",
    "-1",
    "0",
    "7",
    "3.5",
    "Xrotation",
    "Zposition",
    "\n",
    "\t",
    " ",
    "",
    "\x00",
    "é",
    "Hips",
    "-0",
    "1e-320",
    "99999999999999999999",
]


@st.composite
def _mutated(draw) -> str:
    words = GOOD.replace("\n", " \n ").split(" ")
    for _ in range(draw(st.integers(1, 6))):
        i = draw(st.integers(0, len(words) - 1))
        op = draw(st.sampled_from(["replace", "delete", "insert", "duplicate"]))
        token = draw(st.sampled_from(_TOKENS) | st.text(max_size=4))
        if op == "replace":
            words[i] = token
        elif op == "delete":
            del words[i]
        elif op == "insert":
            words.insert(i, token)
        else:
            words[i:i] = words[i : i + draw(st.integers(1, 12))]
    return " ".join(words)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
@given(_mutated())
def test_fuzzed_files_are_read_or_refused_with_a_bvh_error(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("fuzz") / "f.bvh"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    for read in (lambda: bvh.parse(text, "f.bvh"), lambda: bvh.read(path)):
        try:
            m = read()
        except StyleERDError as e:
            assert str(e).startswith(("f.bvh", str(path))) and "\n" not in str(e)
        else:
            assert np.isfinite(m.rotations).all() and np.isfinite(m.positions).all()


def test_every_argument_of_every_command_says_what_it_is():
    """``styleerd COMMAND -h`` is what users read: no option or positional without a help text."""
    import argparse

    from styleerd.cli import build_parser

    def parsers(name: str, parser: argparse.ArgumentParser):
        yield name, parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub, p in action.choices.items():
                    yield from parsers(f"{name} {sub}".strip(), p)

    silent = [
        f"{name}: {'/'.join(a.option_strings) or a.dest}"
        for name, parser in parsers("", build_parser())
        for a in parser._actions
        if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)) and not a.help
    ]
    assert not silent, silent
