"""Every clip of ../shared/data: BVH round trip, feature reconstruction, labels and split.

Slow-ish (all 2,945 clips, on every core); CI always runs it."""

from __future__ import annotations

import os
from multiprocessing import get_context

import numpy as np
import pytest

from styleerd.data import cache as cache_mod
from styleerd.data.cache import FeatureParams, prepare, summary
from styleerd.data.datasets import COMBINED, DATASETS, find_clips, load_motion

SOURCES = [d for d in DATASETS if d not in COMBINED]  # each file once (the combined set lists two of them again)
from styleerd.data.features import features_to_motion, motion_features
from styleerd.data.windows import gather_windows, window_starts
from styleerd.motion import bvh
from styleerd.motion.kinematics import forward_kinematics

pytestmark = pytest.mark.slow


def fk(m):
    return forward_kinematics(m.rotations, m.positions, m.skeleton.parents)[1]


def check_clip(clip) -> tuple[str, float, float, float, float]:
    """(name, channel rel. error, FK error after round trip, FK error of the reconstruction,
    FK error of dropping Bandai's placeholder root)."""
    raw = bvh.read(clip.path)
    again = bvh.parse(bvh.format_bvh(raw))
    a, b = bvh.channel_values(raw), bvh.channel_values(again)
    channel_err = float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(a)), initial=0.0))
    fk_err = float(np.abs(fk(raw) - fk(again)).max())
    motion = load_motion(clip)
    feats, traj = motion_features(motion)
    back = features_to_motion(feats, traj, motion.skeleton, motion.fps)
    recon_err = float(np.abs(fk(back) - fk(motion)).max())
    drop_err = float(np.abs(fk(raw)[:, raw.skeleton.n_joints - motion.skeleton.n_joints :] - fk(motion)).max())
    return clip.name, channel_err, fk_err, recon_err, drop_err


@pytest.fixture(scope="module")
def all_clips(shared_data):
    return {d: find_clips(shared_data, d) for d in SOURCES}


def test_clip_counts_and_labels(all_clips):
    b2, b1, xia = all_clips["bandai-namco-2"], all_clips["bandai-namco-1"], all_clips["xia-sample"]
    assert len(b2) == 2762 and len(b1) == 174 and len(xia) == 9
    assert sorted({c.style for c in b2}) == [
        "active",
        "elderly",
        "exhausted",
        "feminine",
        "masculine",
        "normal",
        "youthful",
    ]
    assert len({c.content for c in b2}) == 10 and len({(c.style, c.content) for c in b2}) == 70
    for c in b2:  # labels from JSON agree with the file name dataset-2_{content}_{style}_{take}
        assert c.name == f"dataset-2_{c.content}_{c.style}_{c.name.rsplit('_', 1)[1]}"
    assert len({c.style for c in b1}) == 15
    assert {c.style for c in xia} == {"angry", "depressed", "neutral", "old", "sexy", "strutting"}
    assert {c.name: c.content for c in xia}["depressed_18_000"] == "punch"


def test_every_clip_round_trips_and_reconstructs(all_clips):
    clips = [c for d in SOURCES for c in all_clips[d]]
    with get_context("spawn").Pool(os.cpu_count()) as pool:
        results = pool.map(check_clip, clips, chunksize=32)
    failures = [r for r in results if not (r[1] <= 1e-5 and r[2] <= 1e-4 and r[3] <= 1e-3 and r[4] <= 1e-3)]
    worst = np.max([r[1:] for r in results], axis=0)
    print(
        f"\n{len(results)} clips; worst channel rel. error {worst[0]:.2e}, round-trip FK {worst[1]:.2e}, "
        f"reconstruction FK {worst[2]:.2e}, root drop FK {worst[3]:.2e}; failures: {len(failures)}"
    )
    assert len(results) == 2762 + 174 + 9
    assert failures == []


def test_prepare_builds_a_cache_that_is_current_split_and_windowed(shared_data, tmp_path, monkeypatch):
    fs = prepare("xia-sample", shared_data, cache=tmp_path, progress=False, workers=1)
    assert fs.path.is_file() and len(fs.names) == 9 and fs.features.shape[1] == 10 * 31 + 4
    assert fs.source_frames.sum() == 1904 and len(fs.features) < 1904  # 120 -> 30 fps
    assert "xia-sample: 9 clips, 6 styles x 4 contents, 1,904 frames" in summary(fs)
    mtime = fs.path.stat().st_mtime_ns
    assert prepare("xia-sample", shared_data, cache=tmp_path, progress=False).path.stat().st_mtime_ns == mtime
    monkeypatch.setattr(cache_mod, "CODE_VERSION", cache_mod.CODE_VERSION + 1)
    rebuilt = prepare("xia-sample", shared_data, cache=tmp_path, progress=False, workers=1)
    assert rebuilt.path != fs.path and rebuilt.path.is_file()
    assert not fs.path.exists()  # the cache it replaces is removed: nothing loads it again
    foreign = tmp_path / "features-xia-sample-not-ours.npz"
    foreign.write_bytes(b"not a cache")
    other = prepare("xia-sample", shared_data, FeatureParams(fps=60.0), cache=tmp_path, progress=False, workers=1)
    assert other.path != rebuilt.path and len(other.features) > len(rebuilt.features)
    assert rebuilt.path.is_file() and foreign.is_file()  # other parameters' cache, and a file not ours, are kept


def test_bandai2_split_and_windows(shared_data):
    fs = prepare("bandai-namco-2", shared_data, progress=False)
    assert len(fs.names) == 2762 and fs.source_frames.sum() == len(fs.features)
    groups = {}
    for name, split, style, content in zip(fs.names, fs.splits, fs.styles, fs.contents):
        groups.setdefault((style, content), set()).add(str(split))
    assert len(groups) == 70 and all(g == {"train", "val", "test"} for g in groups.values())
    assert len(set(fs.names)) == len(fs.names)  # one file, one take, one split
    counts = {s: int((fs.splits == s).sum()) for s in ("train", "val", "test")}
    assert counts["test"] > 200 and counts["train"] > 4 * counts["test"]
    starts = window_starts(fs.clip_start, fs.clips("train"), 24, 20)
    w = gather_windows(fs.features, starts, 24)
    assert w.shape[1:] == (24, fs.features.shape[1]) and len(w) > 10000
    clip_of = np.searchsorted(fs.clip_start, starts, side="right") - 1
    assert np.all(starts + 24 <= fs.clip_start[clip_of + 1])  # no window crosses a clip
    stats = fs.stats()
    x = stats.normalize(fs.features[:5000])
    assert np.isfinite(x).all()
