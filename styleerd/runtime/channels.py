"""ChannelStylizer: raw BVH channel values of one frame in, stylised channel values out, on the
user's own skeleton: retarget to the model's skeleton, StreamStylizer, retarget back, foot
cleanup, Euler angles on the input's branches. What a live mocap or game client streams."""

from __future__ import annotations

import numpy as np

from styleerd.errors import StyleERDError
from styleerd.model.generator import StyleERD
from styleerd.motion import bvh
from styleerd.motion.motion import Motion
from styleerd.motion.retarget import to_source, to_target
from styleerd.motion.skeleton import Skeleton
from styleerd.runtime.cleanup import FootLock
from styleerd.runtime.offline import map_skeleton
from styleerd.runtime.stylizer import StreamStylizer


class ChannelStylizer:
    def __init__(
        self,
        model: StyleERD,
        skeleton: Skeleton,
        target: dict[str, float],
        input_style: str | None = None,
        content: str | None = None,
        fps: float = 30.0,
        n_streams: int = 1,
        explicit_map: dict[str, str] | None = None,
        cleanup: bool = True,
        backend: str = "numpy",
    ):
        self.map = map_skeleton(skeleton, model.skeleton, explicit_map)
        self.skeleton, self.fps, self.n = skeleton, fps, n_streams
        self.n_channels = sum(len(c) for c in skeleton.channels)
        self.stylizer = StreamStylizer(model, input_style, content, target, n_streams, fps, backend=backend)
        self.lock = FootLock(skeleton, n_streams, fps) if cleanup else None

    def reset(self) -> None:
        self.stylizer.reset()
        if self.lock:
            self.lock.reset()

    def step(self, values: np.ndarray) -> np.ndarray:
        """Channel values ``[N, n_channels]`` (or ``[n_channels]`` for one stream) of this
        frame -> the stylised frame's values, same layout. Non-finite values are rejected
        with an error and leave every state unchanged."""
        values = np.asarray(values, dtype=np.float64).reshape(self.n, self.n_channels)
        if not np.isfinite(values).all():
            stream, channel = np.argwhere(~np.isfinite(values))[0]
            raise StyleERDError(f"frame rejected: stream {stream}, channel {channel} is not a finite number")
        source = bvh.motion_from_channels(self.skeleton, values, self.fps)  # the N streams as N "frames"
        on_model = to_target(source, self.map)
        rot, pos = self.stylizer.step(on_model.rotations, on_model.positions)
        out = to_source(Motion(self.map.target, rot, pos, self.fps), self.map, source)
        if self.lock:
            out.rotations = self.lock.step(out.rotations, out.positions, source.rotations, source.positions)
        return bvh.channel_values(out)
