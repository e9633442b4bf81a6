"""``styleerd transfer`` on several files and folders: a process pool, one bad file reported and
skipped, every other file written exactly as a single transfer writes it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from styleerd.motion import bvh, procedural

CLI = [sys.executable, "-m", "styleerd.cli"]


def _cli(*args, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=600, check=False)


def test_folder_with_a_bad_file_writes_the_others_like_single_transfers(tmp_path):
    (tmp_path / "in/sub").mkdir(parents=True)
    bvh.write(tmp_path / "in/a.bvh", procedural.walk(seconds=2.0))
    bvh.write(
        tmp_path / "in/sub/b.bvh",
        procedural.rig_variants(procedural.walk(seconds=2.5))["Blender names and proportions, metres"],
    )
    (tmp_path / "in/sub/broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    (tmp_path / "in/notes.txt").write_text("not motion")
    extra = tmp_path / "c.bvh"
    bvh.write(extra, procedural.walk(seconds=1.5, speed=90.0))
    done = _cli("transfer", "in", extra, "--style", "elderly", "--jobs", 2, "-o", "out", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert "broken.bvh" in done.stderr and "1 of 4 files skipped" in done.stderr and "Traceback" not in done.stderr
    assert "wrote 3 of 4 files" in done.stdout
    assert sorted(p.relative_to(tmp_path / "out").as_posix() for p in (tmp_path / "out").rglob("*.bvh")) == [
        "a.bvh",
        "c.bvh",
        "sub/b.bvh",
    ]
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


def _walks(folder: Path, n: int, seconds: float = 1.0) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(n):
        bvh.write(folder / f"w{k}.bvh", procedural.walk(seconds=seconds, speed=80.0 + k))


def test_a_file_over_the_time_limit_fails_alone_and_resume_skips_what_is_done(tmp_path):
    """``--timeout``: a long file is stopped and skipped, its worker replaced, no partial file left;
    the rest are written. ``--resume`` then transfers only what is missing."""
    _walks(tmp_path / "in", 3)
    bvh.write(tmp_path / "in/long.bvh", procedural.walk(seconds=400.0))
    done = _cli("transfer", "in", "--style", "elderly", "--jobs", 2, "--timeout", 4, "-o", "out", cwd=tmp_path)
    assert done.returncode == 2 and "long.bvh: took longer than --timeout 4 s" in done.stderr, done.stderr[-2000:]
    assert "Traceback" not in done.stderr and "wrote 3 of 4 files" in done.stdout
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "w0.bvh",
        "w1.bvh",
        "w2.bvh",
    ]  # no .tmp of the stopped one
    (tmp_path / "out/w1.bvh").unlink()
    before = (tmp_path / "out/w0.bvh").stat().st_mtime_ns
    again = _cli(
        "transfer", "in", "--style", "elderly", "--jobs", 2, "--timeout", 4, "--resume", "-o", "out", cwd=tmp_path
    )
    log = again.stdout + again.stderr
    assert "w1.bvh -> " in log and "w0.bvh -> " not in log and "long.bvh: took longer" in again.stderr
    assert (tmp_path / "out/w1.bvh").is_file() and (tmp_path / "out/w0.bvh").stat().st_mtime_ns == before
    bad = _cli("transfer", "in", "--style", "elderly", "--timeout", "-1", "-o", "out", cwd=tmp_path)
    assert bad.returncode == 2 and "--timeout -1" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def _children(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` (from /proc: no procps needed)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def test_a_killed_worker_costs_its_file_and_sigterm_stops_everything_cleanly(tmp_path):
    """A worker killed mid-file (what a crash does) fails that file only and is replaced; SIGTERM
    to the batch ends every worker at once and leaves no partial file and no orphan process."""
    import os
    import signal
    import time

    _walks(tmp_path / "in", 6, seconds=90.0)
    proc = subprocess.Popen(
        [*CLI, "transfer", "in", "--style", "elderly", "--jobs", "2", "-o", "out"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 120
    while time.time() < deadline and not (tmp_path / "out").is_dir():  # the workers are at work
        time.sleep(0.2)
    time.sleep(1.0)
    workers = [
        p for p in _children(proc.pid) if "spawn_main" in Path(f"/proc/{p}/cmdline").read_text(errors="replace")
    ]  # not the resource tracker
    assert workers, "no worker process found"
    os.kill(workers[0], signal.SIGKILL)
    out, err = proc.communicate(timeout=600)
    assert "its worker stopped (exit code -9)" in out + err and "Traceback" not in err, err[-2000:]
    assert "wrote 5 of 6 files" in out
    assert not [p for p in (tmp_path / "out").iterdir() if p.suffix != ".bvh"]

    proc = subprocess.Popen(
        [*CLI, "transfer", "in", "--style", "exhausted", "--jobs", "2", "-o", "out2"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    while time.time() < deadline + 120 and not (tmp_path / "out2").is_dir():
        time.sleep(0.2)
    time.sleep(1.0)
    workers = _children(proc.pid)
    started = time.time()
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=60)
    assert time.time() - started < 10 and proc.returncode != 0
    time.sleep(1.0)
    assert not [
        p
        for p in workers
        if Path(f"/proc/{p}").exists() and "zombie" not in Path(f"/proc/{p}/status").read_text().lower()
    ]
    assert not [p for p in (tmp_path / "out2").iterdir() if p.suffix != ".bvh"]


def test_a_numba_batch_measures_the_engine_once_before_its_workers_start(tmp_path, monkeypatch):
    """On a machine never calibrated, the batch's own process measures the numba step's settings
    and its workers read them back: a worker measuring too would write a record of every batch size."""
    from styleerd.runtime import calibration
    from styleerd.runtime.batch import transfer_batch
    from styleerd.runtime.offline import TransferOptions

    monkeypatch.setenv("STYLEERD_CACHE", str(tmp_path / "cache"))  # read by the spawned workers too
    monkeypatch.setattr(calibration, "STREAMS", (1, 4))  # the batch's own measure: two sizes only
    monkeypatch.setattr(calibration, "ROUNDS", 1)
    monkeypatch.setattr(calibration, "_known", {})
    for name in ("a", "b"):
        bvh.write(tmp_path / f"{name}.bvh", procedural.walk(seconds=1.0))
    pairs = [(tmp_path / f"{n}.bvh", tmp_path / "out" / f"{n}.bvh") for n in ("a", "b")]
    assert transfer_batch(pairs, None, TransferOptions({"elderly": 1.0}, backend="numba"), workers=2) == []
    (record,) = (tmp_path / "cache" / "engine").glob("calibration-*.json")
    assert [row["streams"] for row in json.loads(record.read_text())["choices"]] == [1, 4]
    assert all(out.exists() for _, out in pairs)
