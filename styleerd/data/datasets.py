"""Dataset adapters: find the data, unpack archives into a cache, list labelled clips.

Layouts supported:
- Bandai-Namco-Research-Motiondataset-2 and -1 (``*.tar.xz``; labels from ``cfg/*.txt``
  and one JSON per clip);
- the Xia et al. 2015 layout (``{style}_{content-id}_{take}.bvh`` + ``xia_dataset.yml``);
- ``bandai-namco-1+2``: both Bandai-Namco sets as one (same skeleton), Bandai-1's styles that
  Bandai-2 has under another name renamed to Bandai-2's.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

import yaml

from styleerd.errors import StyleERDError
from styleerd.motion import bvh
from styleerd.motion.motion import Motion, drop_root

DATASETS = ("bandai-namco-2", "bandai-namco-1", "xia-sample", "bandai-namco-1+2")
COMBINED = {"bandai-namco-1+2": ("bandai-namco-2", "bandai-namco-1")}
# Bandai-1's styles that are Bandai-2's under another name (active, feminine, normal are
# spelled the same; the other ten have no counterpart and stay as they are)
BANDAI1_AS_BANDAI2 = {"old": "elderly", "tired": "exhausted", "masculinity": "masculine"}
BANDAI1_KEPT_BACK = ("walk-back", "dash", "byebye", "guide")  # and the second walk take


def bandai1_kept_back(name: str, content: str) -> bool:
    """Bandai-1 has one or two takes per style and content, too few for a split by take: these
    five of each style's eleven clips are held out (test) wherever Bandai-1 trains a model, so
    its styles can be judged on clips no model or recogniser of theirs has seen."""
    return content in BANDAI1_KEPT_BACK or (content == "walk" and name.endswith("_002"))


_BANDAI_DIRS = {
    "bandai-namco-2": "Bandai-Namco-Research-Motiondataset-2",
    "bandai-namco-1": "Bandai-Namco-Research-Motiondataset-1",
}


@dataclass(frozen=True)
class Clip:
    dataset: str
    name: str  # file stem; one file is one take
    path: Path
    style: str
    content: str


def data_root(explicit: str | os.PathLike | None = None) -> Path:
    """``explicit``, else ``$STYLEERD_DATA``, else ``../shared/data`` beside the project."""
    if explicit is not None:
        root = Path(explicit)
    elif os.environ.get("STYLEERD_DATA"):
        root = Path(os.environ["STYLEERD_DATA"])
    else:
        candidates = [Path.cwd() / "../shared/data", Path(__file__).resolve().parents[2] / "../shared/data"]
        root = next((c for c in candidates if c.is_dir()), candidates[0])
    if not root.is_dir():
        raise StyleERDError(f"data directory {root} not found (pass --data DIR or set STYLEERD_DATA)")
    return root.resolve()


def cache_dir() -> Path:
    """``$STYLEERD_CACHE``, else ``~/.cache/styleerd``."""
    path = Path(os.environ.get("STYLEERD_CACHE") or Path.home() / ".cache" / "styleerd")
    path.mkdir(parents=True, exist_ok=True)
    return path


def file_digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def unpack(archive: Path, cache: Path | None = None) -> Path:
    """Unpack ``archive`` once into the cache (keyed by its checksum) and return the folder.
    Extraction goes to a temporary folder renamed into place, so a killed run leaves no
    half-unpacked tree behind."""
    cache = cache or cache_dir()
    target = cache / "unpacked" / f"{archive.name.split('.')[0]}-{file_digest(archive)[:16]}"
    if target.is_dir():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=target.parent, prefix=".unpack-"))
    try:
        with tarfile.open(archive, "r:*") as tar:
            tar.extractall(tmp, filter="data")
        os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


def _labels(path: Path, prefix: str) -> list[str]:
    return [line.strip().removeprefix(prefix) for line in path.read_text().splitlines() if line.strip()]


def bandai_clips(root: Path, dataset: str) -> list[Clip]:
    """Clips of an unpacked Bandai-Namco dataset; labels from cfg/*.txt and per-clip JSON."""
    base = root / _BANDAI_DIRS[dataset]
    prefix = "dataset-2_" if dataset == "bandai-namco-2" else "dataset-1_"
    contents = _labels(base / "cfg" / "content_label.txt", prefix)
    styles = _labels(base / "cfg" / "style_label.txt", prefix)
    clips = []
    for path in sorted((base / "data").glob("*.bvh")):
        label_file = path.with_suffix(".json")
        try:
            label = json.loads(label_file.read_text())
            style, content = styles[label["style"]], contents[label["content"]]
        except (OSError, ValueError, KeyError, IndexError, TypeError) as e:
            raise StyleERDError(f"{label_file}: unreadable label ({e})") from None
        clips.append(Clip(dataset, path.stem, path, style, content))
    return clips


def xia_clips(folder: Path, dataset: str = "xia-sample") -> list[Clip]:
    """Clips in the Xia layout: style and content id from the file name, names from the YAML."""
    meta = yaml.safe_load((folder / "xia_dataset.yml").read_text())
    full_names, content_names = meta["content_full_names"], meta["content_names"]
    clips = []
    for path in sorted(folder.glob("*.bvh")):
        try:
            style, cid, _take = path.stem.rsplit("_", 2)
            full = full_names[int(cid) - 1]
        except (ValueError, IndexError):
            raise StyleERDError(f"{path}: name does not follow {{style}}_{{content-id}}_{{take}}.bvh") from None
        content = next((c for c in content_names if full.startswith(c)), None)
        if content is None:
            raise StyleERDError(f"{path}: content {full!r} matches none of {content_names}")
        clips.append(Clip(dataset, path.stem, path, style, content))
    return clips


def find_clips(root: Path, dataset: str, cache: Path | None = None) -> list[Clip]:
    """All labelled clips of ``dataset`` under data folder ``root`` (unpacking if needed)."""
    if dataset in COMBINED:
        parts = [find_clips(root, d, cache) for d in COMBINED[dataset]]
        return parts[0] + [
            Clip(c.dataset, c.name, c.path, BANDAI1_AS_BANDAI2.get(c.style, c.style), c.content) for c in parts[1]
        ]
    if dataset in _BANDAI_DIRS:
        archive = root / f"{dataset}.tar.xz"
        if not archive.is_file():
            raise StyleERDError(f"{archive} not found")
        return bandai_clips(unpack(archive, cache), dataset)
    if dataset == "xia-sample":
        return xia_clips(root / "xia-sample")
    raise StyleERDError(f"unknown dataset {dataset!r}; known: {', '.join(DATASETS)}")


def load_motion(clip: Clip) -> Motion:
    """The clip's motion on the skeleton the model sees. Bandai's static ``joint_Root``
    placeholder is composed into the Hips (exact: forward kinematics are unchanged)."""
    motion = bvh.read(clip.path)
    if clip.dataset in _BANDAI_DIRS and motion.skeleton.names[0] == "joint_Root":
        motion = drop_root(motion)
    return motion
