"""ChannelStylizer: raw BVH channel values of one frame in, stylised channel values out, on the
user's own skeleton: retarget to the model's skeleton, StreamStylizer, retarget back, foot
cleanup, Euler angles on the input's branches. What a live mocap or game client streams."""

from __future__ import annotations

import numpy as np

from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights, LabellerWeights
from styleerd.motion import bvh
from styleerd.motion.motion import Motion
from styleerd.motion.retarget import to_source, to_target
from styleerd.motion.skeleton import Skeleton
from styleerd.runtime.cleanup import FootLock
from styleerd.runtime.offline import map_skeleton
from styleerd.runtime.stylizer import StreamStylizer


class ChannelStylizer:
    """``StreamStylizer`` on the user's skeleton: raw BVH channel values in, stylised channel
    values out, a frame at a time (retargeting both ways, foot cleanup)."""

    def __init__(
        self,
        model: GeneratorWeights,
        skeleton: Skeleton,
        target: dict[str, float],
        input_style: str | None = None,
        content: str | None = None,
        fps: float = 30.0,
        n_streams: int = 1,
        explicit_map: dict[str, str] | None = None,
        cleanup: bool = True,
        backend: str = "numpy",
        labeller: LabellerWeights | None = None,
        first_pose: np.ndarray | None = None,
        parts: str | dict | None = None,
        root_speed: bool = False,
        pose: str = "input",
        threads: int = 1,
    ):
        self.map = map_skeleton(skeleton, model, explicit_map, first_pose=first_pose)
        self.model, self.explicit_map = model, explicit_map
        self.skeleton, self.fps, self.n = skeleton, fps, n_streams
        self.n_channels = sum(len(c) for c in skeleton.channels)
        self.stylizer = StreamStylizer(
            model,
            input_style,
            content,
            target,
            n_streams,
            fps,
            labeller=labeller,
            backend=backend,
            parts=parts,
            root_speed=root_speed,
            pose=pose,
            threads=threads,
        )
        self.lock = FootLock(skeleton, n_streams, fps, legs=self.map.source_legs()) if cleanup else None

    def configure(self, streams, input_style: str | None, content: str | None, target: dict[str, float]) -> None:
        """Labels and target of some streams (a new stream taking a slot; see StreamStylizer)."""
        self.stylizer.configure(streams, input_style, content, target)

    def reset(self, streams=None) -> None:
        """Forget the past of some (default all) streams: their next frame starts a new stream."""
        self.stylizer.reset(streams)
        if self.lock:
            self.lock.reset(streams)

    def step(self, values: np.ndarray, rows=None) -> np.ndarray:
        """Channel values ``[N, n_channels]`` (or ``[n_channels]`` for one stream) of this
        frame -> the stylised frame's values, same layout; of every stream, or of the streams
        ``rows`` only. Non-finite or absurd values are rejected with an error and leave every
        state unchanged."""
        n = self.n if rows is None else len(rows)
        values = np.asarray(values, dtype=np.float64).reshape(n, self.n_channels)
        bad = bvh.channel_problem(self.skeleton, values)  # NaN, inf, or absurd (wrong units, garbage)
        if bad is not None:
            raise StyleERDError(f"frame rejected: stream {bad[0] if rows is None else rows[bad[0]]}: {bad[1]}")
        return bvh.channel_values(self.step_pose(bvh.motion_from_channels(self.skeleton, values, self.fps), rows))

    def step_pose(self, source: Motion, rows=None) -> Motion:
        """The same on poses: ``source`` holds this frame of the N streams (or of ``rows``) as
        N "frames" of local rotations and translations on the user's skeleton."""
        if self.map.wants_first_frame:  # a rest pose that says nothing about bone rolls: the first frame seen does
            self.map = map_skeleton(self.skeleton, self.model, self.explicit_map, first_pose=source.rotations[0])
        on_model = to_target(source, self.map)
        rot, pos = self.stylizer.step(on_model.rotations, on_model.positions, rows)
        out = to_source(Motion(self.map.target, rot, pos, self.fps), self.map, source)
        if self.stylizer.root_speed:  # the root moved at the style's pace (model units, back to the user's)
            out.positions[:, 0] += (pos[:, 0] - on_model.positions[:, 0]) / self.map.scale
        if self.lock:
            out.rotations, out.positions = self.lock.step(
                out.rotations, out.positions, source.rotations, source.positions, rows
            )
        return out
