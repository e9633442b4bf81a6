"""Stylise whole motions and BVH files: exactly the streaming path, frame by frame."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from styleerd.errors import StyleERDError
from styleerd.model.generator import StyleERD
from styleerd.motion import bvh
from styleerd.motion.gltf import write_glb
from styleerd.motion.motion import Motion
from styleerd.motion.resample import resample
from styleerd.motion.retarget import JointMap, body_parts, joint_map, to_source, to_target
from styleerd.motion.skeleton import Skeleton
from styleerd.runtime.cleanup import clean_feet
from styleerd.runtime.stylizer import StreamStylizer


def stylise_motion(model: StyleERD, motion: Motion, input_style: str | None, content: str | None, target: dict[str, float], backend: str = "numpy") -> Motion:
    """The motion in the target style(s): joint rotations from the network, root trajectory
    (position and facing) and joint translations from the input. Labels left None are
    inferred online."""
    return run_stream(StreamStylizer(model, input_style, content, target, fps=motion.fps, backend=backend), motion)


def run_stream(stylizer: StreamStylizer, motion: Motion) -> Motion:
    """Feed a motion on the model's skeleton through a stylizer, one frame at a time."""
    out = np.empty_like(motion.rotations)
    for t in range(motion.n_frames):
        out[t] = stylizer.step(motion.rotations[t : t + 1], motion.positions[t : t + 1])[0][0]
    return Motion(motion.skeleton, out, motion.positions.copy(), motion.fps)


def map_skeleton(motion: Motion, model_skeleton: Skeleton, explicit: dict[str, str] | None = None, where: str = "input") -> JointMap:
    """The mapping of the motion's skeleton onto the model's, or a clear error naming what
    is missing."""
    try:
        return joint_map(model_skeleton, motion.skeleton, explicit)
    except ValueError as e:
        raise StyleERDError(f"{where}: {e}") from None


def transfer_file(
    source: str | Path,
    output: str | Path,
    model: StyleERD,
    fps: float,
    input_style: str | None,
    content: str | None,
    target: dict[str, float],
    explicit_map: dict[str, str] | None = None,
    report: Callable[[str], None] | None = None,
    cleanup: bool = True,
    backend: str = "numpy",
) -> Motion:
    """BVH in -> BVH (or binary glTF) out in the target style, on any humanoid skeleton (retargeted to the
    model's and back, at the model's frame rate and back): same skeleton, channel layout, fps,
    frame count and root trajectory as the input; joints the model does not have keep their
    motion. Labels left None are inferred online; with ``cleanup``, feet planted in the input
    are pinned in the output (on the input's skeleton, after retargeting back). ``report`` receives the joint mapping and the
    labels used. Nothing is written unless the whole transfer succeeded."""
    writers = {".bvh": bvh.write, ".glb": write_glb}
    if Path(output).suffix.lower() not in writers:
        raise StyleERDError(f"{output}: the output must be .bvh or .glb")
    motion = bvh.read(source)
    if motion.n_frames == 0:
        raise StyleERDError(f"{source}: the motion has no frames")
    if not 10 <= motion.fps <= 480:
        raise StyleERDError(f"{source}: {motion.fps:.6g} fps is outside [10, 480]")
    jm = map_skeleton(motion, model.skeleton, explicit_map, str(source))
    if report:
        report(f"joint mapping (model <- input):\n{jm.describe()}")
    stylizer = StreamStylizer(model, input_style, content, target, fps=fps, backend=backend)
    styled = run_stream(stylizer, resample(to_target(motion, jm), fps))
    if report and stylizer.labeller is not None:
        style, kind = stylizer.inferred_labels()[0]
        report(f"input labels at the last frame: style {style}, content {kind} (inferred online where not given)")
    out = to_source(resample(styled, motion.fps, n_frames=motion.n_frames), jm, motion)
    if cleanup:
        parts = body_parts(motion.skeleton)
        out = clean_feet(out, motion, legs=[[parts[f"{side}_{p}"] for p in ("hip", "knee", "foot")] for side in ("left", "right")])
    if not (np.isfinite(out.rotations).all() and np.isfinite(out.positions).all()):
        raise StyleERDError(f"{source}: the transfer produced non-finite values; nothing written")
    writers[Path(output).suffix.lower()](output, out)
    return out
