"""Shared fixtures: synthetic skeletons/motions, and the real data folder (skip only when absent)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from styleerd.motion import quat
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import Skeleton

SHARED_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
ROOT = Path(__file__).resolve().parents[1]


def run_checked(args: list, **kw) -> subprocess.CompletedProcess:
    """A command that must succeed; its output tail is the failure message."""
    done = subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=900, check=False, **kw)
    assert done.returncode == 0, f"{args}: {done.stdout[-2000:]}\n{done.stderr[-4000:]}"
    return done


@pytest.fixture(scope="session")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from this checkout (models and the vendored viewer inside)."""
    out = tmp_path_factory.mktemp("wheel")
    run_checked([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", out, ROOT])
    (path,) = out.glob("styleerd-*.whl")
    return path


@pytest.fixture(scope="session")
def shared_data() -> Path:
    root = Path(os.environ.get("STYLEERD_DATA") or SHARED_DATA)
    if not (root / "bandai-namco-2.tar.xz").is_file():
        pytest.skip(f"real data not found at {root} (CI always has ../shared/data)")
    return root.resolve()


def biped_skeleton(scale: float = 1.0) -> Skeleton:
    """A small humanoid with Bandai-style names, Y up, facing +Z at rest."""
    joints = [
        ("Hips", -1, [0, 90, 0]),
        ("Spine", 0, [0, 10, 0]),
        ("Chest", 1, [0, 15, 0]),
        ("Head", 2, [0, 25, 0]),
        ("UpperArm_L", 2, [15, 20, 0]),
        ("LowerArm_L", 4, [25, 0, 0]),
        ("UpperArm_R", 2, [-15, 20, 0]),
        ("LowerArm_R", 6, [-25, 0, 0]),
        ("UpperLeg_L", 0, [9, -5, 0]),
        ("LowerLeg_L", 8, [0, -40, 0]),
        ("Foot_L", 9, [0, -40, 0]),
        ("Toes_L", 10, [0, -5, 12]),
        ("UpperLeg_R", 0, [-9, -5, 0]),
        ("LowerLeg_R", 12, [0, -40, 0]),
        ("Foot_R", 13, [0, -40, 0]),
        ("Toes_R", 14, [0, -5, 12]),
    ]
    rot = ("Zrotation", "Xrotation", "Yrotation")
    return Skeleton(
        names=tuple(n for n, _, _ in joints),
        parents=np.array([p for _, p, _ in joints]),
        offsets=np.array([o for _, _, o in joints], float) * scale,
        channels=tuple((("Xposition", "Yposition", "Zposition") + rot) if p < 0 else rot for _, p, _ in joints),
        end_sites=((3, np.array([0, 10.0, 0])), (5, np.array([20.0, 0, 0])), (7, np.array([-20.0, 0, 0]))),
    )


def walking_motion(n_frames: int = 60, fps: float = 30.0, seed: int = 0, skeleton: Skeleton | None = None) -> Motion:
    """A smooth synthetic walk-like motion on ``skeleton`` (``biped_skeleton``'s, without hands, by
    default): a turning path, swinging limbs."""
    rng = np.random.default_rng(seed)
    sk = skeleton or biped_skeleton()
    t = np.arange(n_frames) / fps
    J = sk.n_joints
    amp = rng.uniform(0.1, 0.6, size=(J, 3))
    freq = rng.uniform(0.5, 2.0, size=(J, 3))
    phase = rng.uniform(0, 2 * np.pi, size=(J, 3))
    euler = amp * np.sin(2 * np.pi * freq * t[:, None, None] + phase)
    yaw = 0.4 * t + 0.3
    euler[:, 0, 2] += yaw  # root: the last of z, x, y is the yaw about Y
    rotations = quat.from_euler(euler, "zxy")
    positions = np.broadcast_to(sk.offsets, (n_frames, J, 3)).copy()
    positions[:, 0] = np.stack([100 * np.sin(yaw), 90 + 2 * np.sin(6 * t), 100 * np.cos(yaw)], -1)
    return Motion(sk, rotations, positions, fps)


def pytest_configure(config):
    # Tests run beside other work on a 2-core machine: one intra-op thread keeps them fast
    # and their numbers reproducible.
    import torch

    torch.set_num_threads(1)
