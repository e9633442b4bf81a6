"""Motion of other performers on other rigs, and what every training run keeps out of it.

A fixed part of the outside material is held out of every training run
(``held_out``), so the figures measured on it (``styleerd eval actions``, ``eval labels``) are on
motion no model or labeller has seen.
"""

from __future__ import annotations

# Held out of every training run, whole subjects or whole actions: (source, file stems)
CMU_HELD_OUT = {"iclone": ("002_",), "asf-names": ("126_",)}
CMU_REPORTED_SWIMS = (
    "126_01",
    "126_05",
    "126_09",
)  # three of subject 126's thirteen strokes, so swimming does not outweigh the rest
BANDAI1_ACTIONS = ("call", "dance-long", "dance-short", "kick", "punch", "respond", "slash")
XIA_ACTIONS = {"16": "jump", "18": "punch"}


def held_out(clip_name: str, dataset: str, content: str = "", style: str = "") -> bool:
    """Whether a clip is in the held-out set every training run leaves out."""
    if dataset == "cmu-sample":
        return any(clip_name.startswith(p) for prefixes in CMU_HELD_OUT.values() for p in prefixes)
    if dataset == "bandai-namco-1":
        return style == "normal" and content in BANDAI1_ACTIONS
    return dataset == "xia-sample"
