"""Motion of other performers on other rigs, and what every training run keeps out of it.

cmu-sample's two rig families (Character Creator ``CC_Base_*`` and CMU ASF names) need joint
maps (``RIG_MAPS``); a fixed part of the outside material is held out of every training run
(``held_out``), so the figures measured on it (``styleerd eval actions``, ``eval labels``) are on
motion no model or labeller has seen.
"""

from __future__ import annotations

# Joint maps (model joint -> the rig's joint) for the two rig families of cmu-sample, which the
# automatic mapping does not know yet (Character Creator, CMU ASF names)
RIG_MAPS = {
    "cc-base": {
        "Hips": "CC_Base_Hip",
        "Spine": "CC_Base_Spine01",
        "Chest": "CC_Base_Spine02",
        "Neck": "CC_Base_NeckTwist01",
        "Head": "CC_Base_Head",
        **{
            f"{m}_{s}": f"CC_Base_{s}_{c}"
            for s in "LR"
            for m, c in (
                ("Shoulder", "Clavicle"),
                ("UpperArm", "Upperarm"),
                ("LowerArm", "Forearm"),
                ("Hand", "Hand"),
                ("UpperLeg", "Thigh"),
                ("LowerLeg", "Calf"),
                ("Foot", "Foot"),
                ("Toes", "ToeBase"),
            )
        },
    },
    "cmu-asf": {
        "Spine": "lowerback",
        "Chest": "Chest2",
        "Neck": "Neck",
        **{
            f"{m}_{s}": f"{side}{c}"
            for s, side in (("L", "Left"), ("R", "Right"))
            for m, c in (
                ("Shoulder", "Collar"),
                ("UpperArm", "Shoulder"),
                ("LowerArm", "Elbow"),
                ("Hand", "Wrist"),
                ("UpperLeg", "Hip"),
                ("LowerLeg", "Knee"),
                ("Foot", "Ankle"),
                ("Toes", "Toe"),
            )
        },
    },
}
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
