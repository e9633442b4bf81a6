"""Atomic file writes: write beside the target, flush it to disk, then rename into place, so a
failure, a kill or a power cut never leaves a partly written file behind. A temporary file
left by a killed writer (its name carries the writer's process id) is removed by the next
write of the same file."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

from styleerd.errors import StyleERDError


def check_output(path: str | os.PathLike, *inputs: str | os.PathLike) -> Path:
    """Fail early, with one line, where ``path`` cannot be written: its folder is missing or
    not writable, it is a folder, or it is one of the ``inputs`` (it would replace them)."""
    path = Path(path)
    folder = path.parent
    if path.is_dir():
        raise StyleERDError(f"{path}: the output is a folder; give a file name")
    if not folder.is_dir():
        raise StyleERDError(f"{path}: the output's folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise StyleERDError(f"{path}: the output's folder {folder} is not writable")
    for source in inputs:
        if path.exists() and Path(source).exists() and os.path.samefile(path, source):
            raise StyleERDError(f"{path}: the output is the input file; write to another file")
    return path


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_orphans(path: str | os.PathLike) -> None:
    """Temporary files of ``path`` (any suffix) whose writer process is gone."""
    path = Path(path)
    for tmp in path.parent.glob(f".{path.name}.*"):
        pid = tmp.name[len(path.name) + 2 :].split(".", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _pid_alive(int(pid)):
            tmp.unlink(missing_ok=True)


def _fsync(path: str | os.PathLike, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write(path: str | os.PathLike, write: Callable[[str], None], suffix: str = ".tmp") -> None:
    """Call ``write(tmp_path)`` and rename the result to ``path`` (mode 0644 less umask). An
    operating-system failure (missing folder, no permission, a full disk, a file-size limit)
    becomes one ``StyleERDError`` naming ``path``; nothing is left behind."""
    path = Path(path)
    tmp = None
    try:
        remove_orphans(path)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=suffix)
        os.close(fd)
        write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        _fsync(tmp)
        os.replace(tmp, path)
        tmp = None
    except OSError as e:
        raise StyleERDError(f"cannot write {path}: {e.strerror or e}") from None
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
    try:  # the rename itself to disk; some file systems cannot sync a folder, and the file is in place
        _fsync(path.parent, directory=True)
    except OSError:
        pass


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    def write(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)

    atomic_write(path, write)
