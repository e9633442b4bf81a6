"""``styleerd transfer`` on several files and folders: a process pool, one bad file reported and
skipped, every other file written exactly as a single transfer writes it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from styleerd.motion import bvh, procedural

CLI = [sys.executable, "-m", "styleerd.cli"]


def _cli(*args, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=600)


def test_folder_with_a_bad_file_writes_the_others_like_single_transfers(tmp_path):
    (tmp_path / "in/sub").mkdir(parents=True)
    bvh.write(tmp_path / "in/a.bvh", procedural.walk(seconds=2.0))
    bvh.write(tmp_path / "in/sub/b.bvh", procedural.rig_variants(procedural.walk(seconds=2.5))["Blender names and proportions, metres"])
    (tmp_path / "in/sub/broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    (tmp_path / "in/notes.txt").write_text("not motion")
    extra = tmp_path / "c.bvh"
    bvh.write(extra, procedural.walk(seconds=1.5, speed=90.0))
    done = _cli("transfer", "in", extra, "--style", "elderly", "--jobs", 2, "-o", "out", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert "broken.bvh" in done.stderr and "1 of 4 files skipped" in done.stderr and "Traceback" not in done.stderr
    assert "wrote 3 of 4 files" in done.stdout
    assert sorted(p.relative_to(tmp_path / "out").as_posix() for p in (tmp_path / "out").rglob("*.bvh")) == ["a.bvh", "c.bvh", "sub/b.bvh"]
    assert not list((tmp_path / "out").rglob("*.tmp*"))
    for source, batch in (("in/a.bvh", "out/a.bvh"), ("in/sub/b.bvh", "out/sub/b.bvh"), ("c.bvh", "out/c.bvh")):
        single = _cli("transfer", source, "--style", "elderly", "-o", "single.bvh", cwd=tmp_path)
        assert single.returncode == 0, single.stderr
        assert (tmp_path / batch).read_bytes() == (tmp_path / "single.bvh").read_bytes()


def test_batch_argument_errors_are_one_line(tmp_path):
    bvh.write(tmp_path / "a.bvh", procedural.walk(seconds=1.0))
    (tmp_path / "x").mkdir()
    bvh.write(tmp_path / "x/a.bvh", procedural.walk(seconds=1.0))
    (tmp_path / "file.bvh").write_text("")
    (tmp_path / "empty").mkdir()
    for args, message in (
        (["a.bvh", "x", "-o", "out"], "would both be written to"),
        (["a.bvh", "x", "-o", "file.bvh"], "need a folder"),
        (["empty", "-o", "out"], "no motion files"),
        (["a.bvh", "missing.bvh", "-o", "out"], "missing.bvh: no such file or folder"),
        (["a.bvh", "x", "--jobs", "0", "-o", "out"], "--jobs"),
    ):
        done = _cli("transfer", *args, "--style", "elderly", cwd=tmp_path)
        assert done.returncode == 2 and message in done.stderr and "Traceback" not in done.stderr, (args, done.stderr)
        assert not (tmp_path / "out").exists()


def test_batch_to_another_kind(tmp_path):
    (tmp_path / "in").mkdir()
    for name in ("a", "b"):
        bvh.write(tmp_path / f"in/{name}.bvh", procedural.walk(seconds=1.0))
    done = _cli("transfer", "in", "--style", "feminine", "--to", "glb", "-o", "out", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in Path(tmp_path / "out").iterdir()) == ["a.glb", "b.glb"]


def test_one_file_into_a_folder_takes_its_name_and_reports_like_a_single_transfer(tmp_path):
    bvh.write(tmp_path / "walk.bvh", procedural.walk(seconds=1.0))
    (tmp_path / "out").mkdir()
    done = _cli("transfer", "walk.bvh", "--style", "elderly", "-o", "out", cwd=tmp_path)
    assert done.returncode == 0 and "joint mapping" in done.stdout and "wrote out/walk.bvh" in done.stdout, done.stderr
    done = _cli("transfer", "walk.bvh", "--style", "elderly", "-o", "new/", cwd=tmp_path)
    assert done.returncode == 0 and (tmp_path / "new/walk.bvh").is_file()
    done = _cli("transfer", "walk.bvh", "--style", "nope", "-o", "other/", cwd=tmp_path)
    assert done.returncode == 2 and not (tmp_path / "other").exists()
