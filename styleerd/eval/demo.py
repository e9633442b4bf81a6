"""``styleerd demo``: the main job end to end on a bundled input, into every style.

The bundled input is a procedural walk on a Mixamo-named T-pose skeleton at 60 fps (made by
``motion.procedural``, so no dataset clip ships): it goes through retargeting, resampling,
the per-frame stylizer, foot cleanup and back, into every style, at half intensity, and as a
two-style mixture. With the datasets present, a real neutral test walk joins in. Everything
lands in one folder: the BVH files, an HTML page that plays them side by side, a summary.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from styleerd.data.datasets import data_root, find_clips
from styleerd.data.windows import split_takes
from styleerd.errors import StyleERDError
from styleerd.eval.viewer import write_html
from styleerd.model.stored import load_generator_weights
from styleerd.motion import bvh
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.procedural import walk
from styleerd.runtime.offline import TransferOptions, transfer_file


def _mean_change_cm(a, b) -> float:
    ga = forward_kinematics(a.rotations, a.positions, a.skeleton.parents)[1]
    gb = forward_kinematics(b.rotations, b.positions, b.skeleton.parents)[1]
    return float(np.linalg.norm(ga - gb, axis=-1).mean())


def run_demo(out: Path, data_dir: str | None = None) -> str:
    out.mkdir(parents=True, exist_ok=True)
    model = load_generator_weights()
    meta = model.meta
    c = model.config
    inputs = [("generated walk", out / "input-walk.bvh", "normal", "walk")]
    bvh.write(inputs[0][1], walk())
    try:
        clips = find_clips(data_root(data_dir), "bandai-namco-2")
        split = split_takes({k.name: (k.dataset, k.style, k.content) for k in clips})
        real = next(k for k in clips if split[k.name] == "test" and k.style == c.neutral_style and k.content == "walk")
        inputs.append((f"Bandai test clip {real.name}", real.path, None, None))  # labels inferred online
    except (StyleERDError, StopIteration):
        pass
    targets = [(style, style, {style: 1.0}) for style in c.styles if style != c.neutral_style]
    if {"elderly", "feminine", "exhausted"} <= set(c.styles):
        targets += [
            ("elderly at intensity 0.5", "elderly-0.5", {"elderly": 0.5, c.neutral_style: 0.5}),
            ("mix feminine + exhausted", "feminine+exhausted", {"feminine": 0.5, "exhausted": 0.5}),
        ]
    lines = [f"{'input':<28} {'output':<34} {'frames':>6} {'fps':>4} {'mean joint change':>18}"]
    rows = []
    for label, path, style, content in inputs:
        source = bvh.read(path)
        rows.append((f"{label} (input)", source))
        stem = "generated" if style else "real"
        for name, suffix, weights in targets:
            target = out / f"{stem}-{suffix}.bvh"
            transfer_file(
                path, target, model, meta["data"]["fps"], TransferOptions(weights, input_style=style, content=content)
            )
            result = bvh.read(target)
            rows.append((f"-> {name}", result))
            lines.append(
                f"{label[:28]:<28} {target.name:<34} {result.n_frames:>6} {result.fps:>4.0f} "
                f"{_mean_change_cm(source, result):>15.1f} cm"
            )
    write_html(
        out / "index.html",
        rows,
        "styleerd demo: one input, every style",
        f"model {c.styles} x {len(c.contents)} contents; inputs stylised frame by frame, feet cleaned",
    )
    lines.append(f"\nwrote {len(rows)} motions to {out}/ ; open {out / 'index.html'} in a browser")
    return "\n".join(lines)
