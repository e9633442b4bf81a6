"""Skeleton: joint names, parents, rest offsets, and the BVH channel layout that produced it."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
CHANNELS = POSITION_CHANNELS + ROTATION_CHANNELS


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Joints in depth-first order (parents before children; ``parents[0] == -1``).

    ``channels[j]`` is joint j's BVH channel list, kept so the writer reproduces the source
    layout; ``end_sites`` lists (joint index, offset) for every BVH ``End Site``.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_sites: tuple[tuple[int, np.ndarray], ...] = field(default=())

    def __post_init__(self) -> None:
        object.__setattr__(self, "parents", np.asarray(self.parents, dtype=np.int64))
        object.__setattr__(self, "offsets", np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3))
        if not (len(self.names) == len(self.parents) == len(self.offsets) == len(self.channels)):
            raise ValueError("skeleton: names, parents, offsets and channels differ in length")
        if len(self.parents) and (self.parents[0] != -1 or np.any(self.parents[1:] >= np.arange(1, len(self.parents)))):
            raise ValueError("skeleton: joints must be in depth-first order with the root first")

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """The index of the joint called ``name``; ``KeyError`` naming it when there is none."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no joint named {name!r}") from None

    def children(self, j: int) -> list[int]:
        """The joints whose parent is ``j``."""
        return [int(c) for c in np.nonzero(self.parents == j)[0]]

    def chain_length(self, top: int, joint: int) -> float:
        """The rest length of the bones from ``joint`` up to its ancestor ``top`` (up to the root, its
        offset left out, where ``top`` is none of them)."""
        length = 0.0
        while joint != top and self.parents[joint] >= 0:
            length += float(np.linalg.norm(self.offsets[joint]))
            joint = int(self.parents[joint])
        return length

    @cached_property
    def rotation_orders(self) -> tuple[str, ...]:
        """Each joint's Euler order of its rotation channels, e.g. "zxy"; axes without a channel are
        appended in x, y, z order (their angle is always zero)."""
        orders = []
        for chans in self.channels:
            listed = [c[0].lower() for c in chans if c in ROTATION_CHANNELS]
            orders.append("".join(listed + [a for a in "xyz" if a not in listed]))
        return tuple(orders)

    @cached_property
    def euler_axes(self) -> np.ndarray:
        """``[J, 3]`` the axes (0, 1, 2: x, y, z) of each joint's Euler order."""
        return np.array([["xyz".index(a) for a in order] for order in self.rotation_orders], dtype=np.int64).reshape(
            -1, 3
        )

    @cached_property
    def channel_layout(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Where each channel goes, as index arrays: (position columns, their joints, their
        axes, rotation columns, their joints, their slots in the joint's Euler order), so a
        frame's values are scattered or gathered in two numpy calls."""
        layout: tuple[list[int], ...] = ([], [], [], [], [], [])
        col = 0
        for j, chans in enumerate(self.channels):
            for c in chans:
                if c in POSITION_CHANNELS:
                    for k, v in enumerate((col, j, POSITION_CHANNELS.index(c))):
                        layout[k].append(v)
                else:
                    for k, v in enumerate((col, j, self.rotation_orders[j].index(c[0].lower()))):
                        layout[3 + k].append(v)
                col += 1
        return tuple(np.array(a, dtype=np.int64) for a in layout)

    def has_positions(self, j: int) -> bool:
        """Whether joint ``j`` has position channels (usually only the root)."""
        return any(c in POSITION_CHANNELS for c in self.channels[j])

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, Skeleton)
            and self.names == other.names
            and np.array_equal(self.parents, other.parents)
            and np.allclose(self.offsets, other.offsets)
            and self.channels == other.channels
        )

    def to_dict(self) -> dict:
        """The skeleton as plain lists, for JSON (``from_dict`` reads it back)."""
        return {
            "names": list(self.names),
            "parents": self.parents.tolist(),
            "offsets": self.offsets.tolist(),
            "channels": [list(c) for c in self.channels],
            "end_sites": [[j, np.asarray(o).tolist()] for j, o in self.end_sites],
        }

    @classmethod
    def from_dict(cls, d: dict) -> Skeleton:
        """The skeleton that ``to_dict`` wrote."""
        return cls(
            names=tuple(d["names"]),
            parents=np.array(d["parents"]),
            offsets=np.array(d["offsets"]),
            channels=tuple(tuple(c) for c in d["channels"]),
            end_sites=tuple((int(j), np.array(o, dtype=np.float64)) for j, o in d.get("end_sites", [])),
        )


@dataclass(frozen=True)
class BodyRoles:
    """The joints that define facing (hips and shoulders, left and right) and the body's up (hips to
    head), the feet, and the leg length."""

    left: tuple[int, ...]  # hip and shoulder: the across vector that defines facing
    right: tuple[int, ...]
    feet: tuple[int, ...]  # left foot, left toe, right foot, right toe
    leg_length: float  # hip to foot, rest pose
    hips: int  # the pelvis joint
    head: int  # -1 where no head joint is found

    @cached_property
    def joint_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(left, right, feet) as index arrays, for compiled loops."""
        return tuple(np.array(j, dtype=np.int64) for j in (self.left, self.right, self.feet))

    @classmethod
    def of(cls, skeleton: Skeleton) -> BodyRoles:
        """Find the roles in ``skeleton`` by joint name and topology (``humanoid.body_parts``; a
        foot with no toe joint stands for its toe too); ``KeyError`` naming a role not found."""
        from styleerd.motion.humanoid import body_parts  # the humanoid module builds on this one

        r = body_parts(skeleton)
        for side in ("left", "right"):
            if f"{side}_foot" in r:
                r.setdefault(f"{side}_toe", r[f"{side}_foot"])
        needed = ("hips", "left_hip", "right_hip", "left_shoulder", "right_shoulder", "left_foot", "right_foot")
        missing = [role.replace("_", " ") for role in needed if role not in r]
        if missing:
            raise KeyError(f"no joint found for {', '.join(missing)}")
        return cls(
            left=(r["left_hip"], r["left_shoulder"]),
            right=(r["right_hip"], r["right_shoulder"]),
            feet=(r["left_foot"], r["left_toe"], r["right_foot"], r["right_toe"]),
            leg_length=skeleton.chain_length(r["left_hip"], r["left_foot"]),
            hips=r["hips"],
            head=r.get("head", -1),
        )
