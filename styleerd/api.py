"""The Python API: a model, a live stylizer on your own skeleton, a transfer of a whole motion.

    import styleerd
    model = styleerd.load()                                 # the shipped model, or a name or path
    live = model.stylizer("elderly", skeleton="me.bvh")    # one live stream on your skeleton
    out = live.step(frame)                                  # BVH channel values in, same layout out
    walk = styleerd.transfer("walk.bvh", "exhausted", output="walk-exhausted.bvh")

No torch is needed: models are read as numpy arrays and stepped by the numpy or numba backend.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights, load_generator_weights
from styleerd.models import LICENCE
from styleerd.motion import bvh
from styleerd.motion.gltf import GLTF_INPUTS, read_gltf_file, read_motion
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import Skeleton
from styleerd.runtime.channels import ChannelStylizer
from styleerd.runtime.offline import TransferOptions, humanoid_joint_map, transfer_file, transfer_motion
from styleerd.runtime.stylizer import label_vector, part_targets, target_weights

PathLike = str | os.PathLike


class Stylizer:
    """One live stream on a skeleton: ``step(frame)`` takes the frame's BVH channel values
    (the skeleton's channel layout, one row) and returns the stylised frame's, with no
    look-ahead; ``set_style`` changes the target mid-stream (blended over a few frames)."""

    def __init__(self, model: Model, channels: ChannelStylizer):
        self.model, self.channels = model, channels
        self.skeleton: Skeleton = channels.skeleton
        self.n_channels: int = channels.n_channels

    def step(self, frame: np.ndarray) -> np.ndarray:
        """Channel values ``[n_channels]`` of this frame -> the stylised frame's values."""
        return self.channels.step(np.asarray(frame, dtype=np.float64).reshape(1, self.n_channels))[0]

    def set_style(
        self, style: str | None = None, *, intensity: float = 1.0, mix: dict[str, float] | None = None
    ) -> None:
        """Switch the target mid-stream (a style at ``intensity``, or a ``mix`` of styles); the
        change is blended over a few frames."""
        self.channels.stylizer.set_target(self.model.target(style, intensity, mix))

    def reset(self) -> None:
        """Forget the past: the next frame starts a new stream."""
        self.channels.reset()


class Model:
    """A trained styleerd model (``styleerd.load()``): its styles, contents and skeleton, and
    what it does (``stylizer``, ``transfer``)."""

    licence = LICENCE

    def __init__(self, weights: GeneratorWeights):
        self.weights = weights
        c = weights.config
        self.styles: tuple[str, ...] = c.styles
        self.contents: tuple[str, ...] = c.contents
        self.neutral_style: str = c.neutral_style
        self.skeleton: Skeleton = weights.skeleton
        self.fps: float = float(weights.meta.get("data", {}).get("fps", 30.0))

    def __repr__(self) -> str:
        return (
            f"<styleerd model: styles {', '.join(self.styles)}; {len(self.contents)} contents; "
            f"{self.skeleton.n_joints} joints at {self.fps:g} fps>"
        )

    def target(
        self, style: str | None = None, intensity: float = 1.0, mix: dict[str, float] | None = None
    ) -> dict[str, float]:
        """Target weights of a style (or a mixture ``{style: weight}``) at an intensity (0 =
        neutral, 1 = the style, up to 2 exaggerates); unknown styles are refused."""
        weights = target_weights(self.weights, style, intensity, mix)
        label_vector(self.styles, weights, "style")  # names the valid styles if one is not
        return weights

    def stylizer(
        self,
        style: str | None = None,
        *,
        intensity: float = 1.0,
        mix: dict[str, float] | None = None,
        skeleton: Skeleton | Motion | PathLike | None = None,
        fps: float | None = None,
        input_style: str | None = None,
        content: str | None = None,
        joint_map: dict[str, str] | None = None,
        cleanup: bool = True,
        backend: str = "numpy",
        parts: str | dict | None = None,
        root_speed: bool = False,
        pose: str = "input",
    ) -> Stylizer:
        """A live stylizer for frames on ``skeleton`` (a ``Skeleton``, a ``Motion``, or a BVH,
        glTF, VRM or VRMA file whose skeleton to use, an avatar with no animation too, mapped by
        its VRM humanoid where it has one; default the model's) at ``fps`` (default: the file's
        animation's, else the model's). Labels left None are inferred online; ``joint_map`` names
        model joints -> your joints where the names do not say; ``cleanup`` pins planted feet;
        ``parts`` gives body parts targets of their own (``{"legs": "elderly", "arms": "input"}``
        or ``"legs=elderly,arms=input"``; ``runtime.stylizer.part_targets``); ``root_speed``
        moves the root at the target style's pace (default: the input's root path); ``pose``
        "input" (default) turns the input's own pose by the style's change, "network" gives the
        network's pose (``runtime.stylizer``)."""
        if skeleton is None:
            skeleton = self.skeleton
        elif isinstance(skeleton, (str, os.PathLike)) and Path(skeleton).suffix.lower() in GLTF_INPUTS:
            character, clips = read_gltf_file(skeleton)  # an avatar, animated or not: its rest pose, its VRM humanoid
            joint_map = humanoid_joint_map(self.weights, character, joint_map) or None
            fps = fps or (clips[0][1].motion.fps if clips else None)
            skeleton = character.motion.skeleton
        elif isinstance(skeleton, (str, os.PathLike)):
            skeleton = read_motion(skeleton)
        if isinstance(skeleton, Motion):
            fps = fps or skeleton.fps
            skeleton = skeleton.skeleton
        channels = ChannelStylizer(
            self.weights,
            skeleton,
            self.target(style, intensity, mix),
            input_style,
            content,
            fps or self.fps,
            explicit_map=joint_map,
            cleanup=cleanup,
            backend=backend,
            parts=parts,
            root_speed=root_speed,
            pose=pose,
        )
        return Stylizer(self, channels)

    def transfer(
        self,
        source: Motion | PathLike,
        style: str | None = None,
        *,
        intensity: float = 1.0,
        mix: dict[str, float] | None = None,
        output: PathLike | None = None,
        input_style: str | None = None,
        content: str | None = None,
        joint_map: dict[str, str] | None = None,
        cleanup: bool = True,
        backend: str = "numpy",
        parts: str | dict | None = None,
        root_speed: bool = False,
        pose: str = "input",
        animation: str = "all",
        keep_original: bool = False,
    ) -> Motion:
        """A whole motion (a ``Motion`` or a BVH/glTF/GLB/VRM file) in the target style, on its
        own skeleton, same frames and fps; also written to ``output`` (.bvh, .glb, .vrm) when
        given (atomically: nothing is written unless the transfer succeeded). ``root_speed``:
        the root's ground speed in the target style too (else the input's root path); ``pose``: as
        for ``stylizer``. From a glTF/VRM file with an ``output``, every animation is stylised
        under its own name (or only ``animation``); ``keep_original`` keeps the input's beside
        them, named NAME-STYLE; the last one written is returned."""
        options = TransferOptions(
            self.target(style, intensity, mix),
            input_style,
            content,
            joint_map,
            cleanup,
            backend,
            parts=part_targets(self.weights, parts) or None,
            root_speed=root_speed,
            pose=pose,
            animation=animation,
            keep_original=keep_original,
        )
        if output is not None and not isinstance(source, Motion):
            transfer_file(source, output, self.weights, self.fps, options)
            return read_motion(output, -1)
        motion = source if isinstance(source, Motion) else read_motion(source)
        out = transfer_motion(motion, self.weights, self.fps, options)
        if output is not None:
            if Path(output).suffix.lower() != ".bvh":
                raise StyleERDError(
                    f"{output}: a motion in memory is written as .bvh; give a file as the source for .glb or .vrm"
                )
            bvh.write(output, out)
        return out


def load(name: PathLike | None = None) -> Model:
    """A model by path, or by name in ``$STYLEERD_MODELS`` or among the shipped ones (default:
    the shipped ``styleerd-bandai2``)."""
    return Model(load_generator_weights(name))


def transfer(source: Motion | PathLike, style: str | None = None, *, model: Model | None = None, **options) -> Motion:
    """``load().transfer(source, style, **options)``: see ``Model.transfer``."""
    return (model or load()).transfer(source, style, **options)
