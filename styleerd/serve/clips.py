"""The viewer's demo clips: a walk the project generates itself (always there), and, when a
data folder is present, a few real Bandai-Namco-2 test clips read from it at run time (never
copied into the project)."""

from __future__ import annotations

import json
from functools import cache
from urllib.parse import unquote

from styleerd.data.datasets import data_root, find_clips
from styleerd.data.windows import split_takes
from styleerd.errors import StyleERDError, unknown_name
from styleerd.model.stored import GeneratorWeights
from styleerd.motion import bvh
from styleerd.motion.procedural import walk
from styleerd.motion.retarget import to_target
from styleerd.runtime.offline import map_skeleton, run_stream
from styleerd.runtime.stylizer import StreamStylizer, label_vector

REAL_CONTENTS = ("walk", "run", "wave-both-hands", "raise-up-both-hands", "walk-turn-left")
REFERENCE_CLIPS = ("walk", "guard")  # the generated walk, and the same with the fists held at the chin


class DemoClips:
    def __init__(self, model: GeneratorWeights, data: str | None = None):
        self.paths = {}
        try:
            clips = find_clips(data_root(data), "bandai-namco-2")
        except StyleERDError:
            clips = []
        split = split_takes({k.name: (k.dataset, k.style, k.content) for k in clips}) if clips else {}
        for content in REAL_CONTENTS:
            for style in (model.config.neutral_style, "elderly"):
                clip = next(
                    (k for k in clips if split[k.name] == "test" and k.style == style and k.content == content), None
                )
                if clip is not None:
                    self.paths[f"bandai {style} {content} ({clip.name})"] = clip.path
        self.generated = {"generated walk (T-pose skeleton, 30 fps)": None}

    def names(self) -> list[str]:
        return list(self.generated) + list(self.paths)

    def bvh_text(self, name: str) -> str | None:
        name = unquote(name)
        if name in self.generated:
            return _generated_walk()
        if name in self.paths:
            return self.paths[name].read_text()
        return None


@cache
def _generated_walk() -> str:
    """The generated demo walk's BVH text: made once (12 s of walk took 20 ms a request)."""
    return bvh.format_bvh(walk(12.0, fps=30.0), precision=5)


def reference_clip(model: GeneratorWeights, style: str, clip: str = "walk") -> bytes:
    """The generated walk (``clip`` "guard": with the fists held at the chin) on the model's
    skeleton (local rotations and translations, flat), and its stylisation into ``style`` by this
    server's stylizer: what the in-browser step (static/engine.html) reproduces and is compared
    with. JSON bytes."""
    c = model.config
    label_vector(c.styles, {style: 1.0}, "style")  # an unknown style is refused, naming the valid ones
    if clip not in REFERENCE_CLIPS:
        raise unknown_name("reference clip", clip, REFERENCE_CLIPS)
    source = walk(seconds=4.0, fps=30.0, guard=clip == "guard")
    on_model = to_target(source, map_skeleton(source.skeleton, model, first_pose=source.rotations[0]))
    stylised = run_stream(StreamStylizer(model, c.neutral_style, "walk", {style: 1.0}, fps=on_model.fps), on_model)
    body = {
        "frames": on_model.n_frames,
        "fps": on_model.fps,
        "input_style": c.neutral_style,
        "content": "walk",
        "style": style,
        "clip": clip,
        "rotations": on_model.rotations.ravel().round(8).tolist(),
        "positions": on_model.positions.ravel().round(6).tolist(),
        "stylised": stylised.rotations.ravel().round(8).tolist(),
    }
    return json.dumps(body).encode()
