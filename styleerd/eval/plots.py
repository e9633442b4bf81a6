"""Stick-figure pictures of motions (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from styleerd.atomic import atomic_write
from styleerd.data.datasets import Clip, load_motion
from styleerd.model.stored import GeneratorWeights
from styleerd.motion import quat
from styleerd.motion.kinematics import facing_directions, forward_kinematics, heading_rotations
from styleerd.motion.motion import Motion
from styleerd.motion.resample import resample
from styleerd.motion.skeleton import BodyRoles
from styleerd.runtime.offline import stylise_motion


def _draw(ax, xy: np.ndarray, parents: np.ndarray, color: str) -> None:
    for j, p in enumerate(parents):
        if p >= 0:
            ax.plot([xy[p, 0], xy[j, 0]], [xy[p, 1], xy[j, 1]], color=color, lw=2.2, solid_capstyle="round")


def screen_poses(motion: Motion, yaw_degrees: float = 35.0) -> np.ndarray:
    """Per frame, joint positions ``[T, J, 2]`` seen by a camera in front of the character and
    turned ``yaw_degrees`` to its side: each pose is put in its own heading frame (facing +Z,
    root above the origin), so every frame is drawn from the same relative viewpoint."""
    _, g = forward_kinematics(motion.rotations, motion.positions, motion.skeleton.parents)
    roles = BodyRoles.of(motion.skeleton)
    heading = heading_rotations(facing_directions(g, roles.left, roles.right))
    local = quat.mul_vec(quat.inv(heading)[:, None], g - g[:, :1] * [1, 0, 1])
    a = np.radians(yaw_degrees)
    return np.stack([-local[..., 0] * np.cos(a) + local[..., 2] * np.sin(a), local[..., 1]], -1)


def filmstrip(rows: list[tuple[str, Motion]], path: str | Path, frames: int = 8, title: str = "") -> None:
    """One row per motion: ``frames`` evenly spaced poses side by side (``screen_poses``)."""
    n = len(rows)
    fig, axes = plt.subplots(n, 1, figsize=(frames * 1.25, 1.9 * n), squeeze=False)
    colors = plt.get_cmap("tab10")
    for r, (label, motion) in enumerate(rows):
        xy = screen_poses(motion)
        idx = np.linspace(0, motion.n_frames - 1, frames).astype(int)
        height = np.ptp(xy[..., 1])
        ax = axes[r, 0]
        for k, t in enumerate(idx):
            _draw(ax, xy[t] + [k * 0.8 * height, 0], motion.skeleton.parents, colors(r % 10))
        ax.set_aspect("equal")
        ax.axis("off")
        ax.set_title(label, loc="left", fontsize=10)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    path = Path(path)
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=90, format=path.suffix.lstrip(".") or "png"))
    plt.close(fig)


def animation(rows: list[tuple[str, Motion]], path: str | Path, fps: float = 15.0, seconds: float = 4.0) -> None:
    """The motions side by side as an animated GIF, a panel each (``screen_poses``), the first
    ``seconds`` of them at ``fps`` frames a second, looping."""
    from PIL import Image

    xys = [screen_poses(resample(m, fps), yaw_degrees=50.0)[: max(1, round(seconds * fps))] for _, m in rows]
    lo, hi = np.min([xy.min((0, 1)) for xy in xys], 0), np.max([xy.max((0, 1)) for xy in xys], 0)
    fig, axes = plt.subplots(1, len(rows), figsize=(2.2 * len(rows), 2.9), squeeze=False)
    colors = plt.get_cmap("tab10")
    images = []
    for t in range(min(len(xy) for xy in xys)):
        for r, ((label, motion), xy) in enumerate(zip(rows, xys)):
            ax = axes[0, r]
            ax.clear()
            _draw(ax, xy[t], motion.skeleton.parents, colors(r % 10))
            ax.set_xlim(lo[0] - 0.05 * (hi[1] - lo[1]), hi[0] + 0.05 * (hi[1] - lo[1]))
            ax.set_ylim(lo[1], hi[1] * 1.05)
            ax.set_aspect("equal")
            ax.axis("off")
            ax.set_title(label, fontsize=10)
        fig.canvas.draw()
        images.append(Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[..., :3]).quantize(16))
    plt.close(fig)
    atomic_write(
        path,
        lambda tmp: images[0].save(
            tmp, format="GIF", save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0
        ),
    )


def style_filmstrip(
    model: GeneratorWeights,
    clip: Clip,
    path: str | Path,
    frames: int = 8,
    cards: str | Path | None = None,
    styles: list[str] | None = None,
) -> None:
    """A neutral clip and its transfer into ``styles`` (default: every other style of ``model``):
    a filmstrip, or an animated GIF when ``path`` ends in ``.gif``; with ``cards``, also one small
    picture per style there (``STYLE.png``, the input as ``STYLE.png`` of its own)."""
    motion = resample(load_motion(clip), 30.0)
    c = model.config
    styles = [s for s in c.styles if s != clip.style] if styles is None else styles
    rows = [(f"input: {clip.name} ({clip.style}, {clip.content})", motion)]
    for style in styles:
        rows.append((f"-> {style}", stylise_motion(model, motion, clip.style, clip.content, {style: 1.0})))
    if Path(path).suffix.lower() == ".gif":
        animation([(f"input ({clip.style})", motion), *rows[1:]], path)
    else:
        title = f"Style-ERD transfers of one test clip ({motion.n_frames} frames at 30 fps)"
        filmstrip(rows, path, frames, title=title)
    if cards:
        Path(cards).mkdir(parents=True, exist_ok=True)
        for (label, moved), style in zip(rows, [clip.style, *styles]):
            filmstrip([(label, moved)], Path(cards) / f"{style}.png", frames=5)
