"""Read and write BVH files of any hierarchy and channel layout.

Reads any rotation channel order on any joint, position channels on any joint, End Sites,
tabs or spaces, trailing spaces, CRLF, zero- and one-frame files. The writer reproduces the
source layout (channel lists, which joints carry positions), so read -> write -> read keeps
every channel value. Malformed input raises one ``BVHError`` naming file, line and problem.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import numba as nb
import numpy as np

from styleerd.atomic import atomic_write_text
from styleerd.errors import StyleERDError
from styleerd.motion import quat
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import CHANNELS, Skeleton

_CANONICAL = {c.lower(): c for c in CHANNELS}
MAX_DEPTH = 256  # joints in one chain: real rigs have tens; deeper is garbage (and Python's recursion limit)
MAX_LINE = 1 << 22  # characters in one line: a frame of 10,000 channels fits; /dev/zero does not
MAX_HEADER_LINES = 1 << 18  # lines before 'Frame Time'
MAX_CHANNEL = 1e7  # |channel value| in BVH units (centimetres, degrees): 100 km or 27,000 turns is garbage, not motion


class BVHError(StyleERDError):
    """A malformed BVH file. ``str(err)`` is ``"FILE:LINE: problem"``."""

    def __init__(self, path: str | os.PathLike, line: int | None, problem: str):
        super().__init__(str(path), line, problem)  # args stay (path, line, problem): picklable
        self.path, self.line, self.problem = str(path), line, problem

    def __str__(self) -> str:
        where = f"{self.path}:{self.line}" if self.line is not None else self.path
        return f"{where}: {self.problem}"


class _Tokens:
    """Whitespace tokens of the HIERARCHY section, each with its 1-based line number."""

    def __init__(self, lines: list[str], path: str):
        self.path = path
        self.items = [(tok, n + 1) for n, line in enumerate(lines) for tok in line.split()]
        self.i = 0
        self.last_line = len(lines) + 1  # the MOTION line, where the hierarchy ends

    def peek(self) -> str | None:
        return self.items[self.i][0] if self.i < len(self.items) else None

    def line(self) -> int:
        return self.items[self.i][1] if self.i < len(self.items) else self.last_line

    def next(self, what: str) -> str:
        if self.i >= len(self.items):
            raise BVHError(self.path, self.last_line, f"unexpected end of HIERARCHY, expected {what}")
        tok = self.items[self.i][0]
        self.i += 1
        return tok

    def expect(self, word: str) -> None:
        line = self.line()
        tok = self.next(repr(word))
        if tok != word:
            raise BVHError(self.path, line, f"expected {word!r}, found {tok!r}")

    def number(self, what: str) -> float:
        line = self.line()
        tok = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise BVHError(self.path, line, f"{what}: {tok!r} is not a number") from None
        if not np.isfinite(value):
            raise BVHError(self.path, line, f"{what}: {tok!r} is not finite")
        if abs(value) >= MAX_CHANNEL:  # an offset as far as no channel may move a joint is garbage too
            raise BVHError(self.path, line, f"{what}: {tok} is out of range (|value| < {MAX_CHANNEL:g})")
        return value

    def rest_of_line(self, line: int) -> list[str]:
        out = []
        while self.i < len(self.items) and self.items[self.i][1] == line and self.items[self.i][0] != "{":
            out.append(self.items[self.i][0])
            self.i += 1
        return out


def _parse_hierarchy(tokens: _Tokens) -> Skeleton:
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_sites: list[tuple[int, np.ndarray]] = []
    path = tokens.path

    def offset(what: str) -> list[float]:
        tokens.expect("OFFSET")
        return [tokens.number(f"{what} OFFSET") for _ in range(3)]

    def joint(parent: int, depth: int) -> None:
        line = tokens.line()
        name = " ".join(tokens.rest_of_line(line))
        if not name:
            raise BVHError(path, line, "joint without a name")
        if depth > MAX_DEPTH:
            raise BVHError(path, line, f"joint {name!r} is {depth} joints deep; at most {MAX_DEPTH} are supported")
        if name in names:
            raise BVHError(path, line, f"duplicate joint name {name!r}")
        j = len(names)
        names.append(name)
        parents.append(parent)
        tokens.expect("{")
        offsets.append(offset(f"joint {name!r}"))
        chans: tuple[str, ...] = ()
        if tokens.peek() == "CHANNELS":
            tokens.next("CHANNELS")
            line = tokens.line()
            count = tokens.number(f"joint {name!r} CHANNELS count")
            if count != int(count) or not 0 <= count <= 6:
                raise BVHError(
                    path, line, f"joint {name!r}: channel count {tokens.items[tokens.i - 1][0]!r} is not 0..6"
                )
            listed = []
            for _ in range(int(count)):
                line = tokens.line()
                tok = tokens.next(f"joint {name!r} channel name")
                if tok.lower() not in _CANONICAL:
                    raise BVHError(path, line, f"joint {name!r}: unknown channel name {tok!r}")
                listed.append(_CANONICAL[tok.lower()])
            if len(set(listed)) != len(listed):
                raise BVHError(path, line, f"joint {name!r}: a channel is listed twice in {listed}")
            chans = tuple(listed)
        channels.append(chans)
        while True:
            line = tokens.line()
            if tokens.peek() is None:
                raise BVHError(path, line, f"missing '}}' closing joint {name!r} before MOTION")
            tok = tokens.next(f"'}}' closing joint {name!r}")
            if tok == "}":
                return
            if tok == "JOINT":
                joint(j, depth + 1)
            elif tok == "End":
                tokens.expect("Site")
                tokens.expect("{")
                end_sites.append((j, np.array(offset(f"End Site of {name!r}"))))
                tokens.expect("}")
            elif tok in ("MOTION", "ROOT"):
                raise BVHError(path, line, f"missing '}}' closing joint {name!r} before {tok}")
            else:
                raise BVHError(path, line, f"expected JOINT, End Site or '}}' in joint {name!r}, found {tok!r}")

    tokens.expect("HIERARCHY")
    line = tokens.line()
    if tokens.next("ROOT") != "ROOT":
        raise BVHError(path, line, "expected ROOT after HIERARCHY")
    joint(-1, 1)
    if tokens.peek() is not None:
        raise BVHError(
            path, tokens.line(), f"unexpected {tokens.peek()!r} after the root joint (only one ROOT is supported)"
        )
    return Skeleton(tuple(names), np.array(parents), np.array(offsets), tuple(channels), tuple(end_sites))


def _frame_values(lines: list[str], first_line: int, n_channels: int, path: str) -> np.ndarray:
    """Parse frame lines into ``[T, n_channels]``; on any problem, name the exact line."""
    if not lines:
        return np.zeros((0, n_channels))
    try:
        with warnings.catch_warnings():  # older numpy warns and stops early on a bad token
            warnings.simplefilter("error", DeprecationWarning)
            flat = np.fromstring(" ".join(lines), sep=" ")
    except (ValueError, DeprecationWarning):  # a bad token: the loop below names it
        flat = np.zeros(0)
    if flat.size == len(lines) * n_channels and all(len(line.split()) == n_channels for line in lines):
        values = flat.reshape(len(lines), n_channels)
        bad = ~np.isfinite(values)
        if not bad.any():
            return values
    for t, line in enumerate(lines):
        toks = line.split()
        for c, tok in enumerate(toks):
            try:
                v = float(tok)
            except ValueError:
                raise BVHError(path, first_line + t, f"frame {t}: {tok!r} is not a number") from None
            if not np.isfinite(v):
                raise BVHError(path, first_line + t, f"frame {t}: value {tok!r} of channel {c} is not finite")
        if len(toks) != n_channels:
            raise BVHError(
                path, first_line + t, f"frame {t}: {len(toks)} values, the hierarchy declares {n_channels} channels"
            )
    raise BVHError(path, first_line, "frame data could not be parsed")  # unreachable in practice


def _parse_header(lines: list[str], path: str) -> tuple[Skeleton, int, float, int]:
    """HIERARCHY and the MOTION header lines -> (skeleton, frame count, frame time, index of
    the first frame line). ``lines`` must reach at least the 'Frame Time' line."""
    starts = [n for n, line in enumerate(lines) if line.strip() == "MOTION"]
    if not starts:
        raise BVHError(path, len(lines), "no MOTION section")
    m = starts[0]
    skeleton = _parse_hierarchy(_Tokens(lines[:m], path))

    def header(n: int, key: str) -> float:
        if n >= len(lines):
            raise BVHError(path, len(lines), f"truncated MOTION section: missing '{key}' line")
        head, _, value = lines[n].strip().partition(":")
        if head.strip() != key:
            raise BVHError(path, n + 1, f"expected '{key}:', found {lines[n].strip()!r}")
        try:
            return float(value)
        except ValueError:
            raise BVHError(path, n + 1, f"'{key}:' value {value.strip()!r} is not a number") from None

    frames = header(m + 1, "Frames")
    if not (np.isfinite(frames) and frames == int(frames) and 0 <= frames < 1 << 40):
        raise BVHError(path, m + 2, f"Frames: {frames!r} is not a frame count")
    frame_time = header(m + 2, "Frame Time")
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise BVHError(path, m + 3, f"Frame Time: {frame_time!r} must be a positive number of seconds")
    return skeleton, int(frames), frame_time, m + 3


def _check_body(body: list[str], n_frames: int, first: int, n_lines: int, path: str) -> None:
    while body and not body[-1].strip():
        body.pop()
    blank = [n for n, line in enumerate(body) if not line.strip()]
    if blank:
        raise BVHError(path, first + 1 + blank[0], "blank line inside the frame data")
    if len(body) < n_frames:
        raise BVHError(
            path, n_lines, f"truncated MOTION section: Frames says {n_frames}, found {len(body)} frame lines"
        )
    if len(body) > n_frames:
        raise BVHError(path, first + 1 + n_frames, f"Frames says {n_frames}, found {len(body)} frame lines")


def parse(text: str, path: str = "<string>") -> Motion:
    """Parse BVH text. ``path`` only names the source in error messages."""
    lines = text.splitlines()
    skeleton, n_frames, frame_time, first = _parse_header(lines, path)
    n_channels = sum(len(c) for c in skeleton.channels)
    if n_channels == 0:  # frame lines are empty: only the count can be checked
        return motion_from_channels(skeleton, np.zeros((n_frames, 0)), 1.0 / frame_time)
    body = lines[first:]
    _check_body(body, n_frames, first, len(lines), path)
    values = _frame_values(body, first + 1, n_channels, path)
    return motion_from_channels(skeleton, values, 1.0 / frame_time)


@dataclass(frozen=True)
class Header:
    """What ``stream`` reads before the frames: the skeleton, the frame count and rate, the file."""

    skeleton: Skeleton
    n_frames: int
    fps: float
    path: str


def _lines(f, path: str, first: int = 1) -> Iterator[str]:
    """The lines of an open text file, each at most ``MAX_LINE`` characters (memory stays
    bounded on a file of one endless line); ``first`` numbers the first in errors."""
    n = first
    while True:
        try:
            line = f.readline(MAX_LINE + 1)
        except UnicodeDecodeError as e:
            raise BVHError(path, n, f"not a text file ({e.reason})") from None
        if not line:
            return
        if len(line) > MAX_LINE:
            raise BVHError(path, n, f"line longer than {MAX_LINE} characters")
        yield line
        n += 1


def stream(path: str | os.PathLike, chunk: int = 1024) -> tuple[Header, Iterator[np.ndarray]]:
    """Read a BVH file's header, and iterate over its frames' channel values in chunks of
    ``chunk`` frames (``[k, n_channels]``), so files of any length use bounded memory. The
    same checks as ``read``; a problem in the frame data raises when its chunk is read."""
    path = str(path)
    try:
        # -sig: a byte-order mark some Windows tools write; the generator below closes the file
        f = open(path, encoding="utf-8-sig", errors="strict")  # noqa: SIM115
    except OSError as e:
        raise BVHError(path, None, e.strerror or str(e)) from None
    try:
        lines, started = [], False
        for line in _lines(f, path):
            lines.append(line.rstrip("\r\n"))
            if not started and line.strip():  # the first line with text
                if not line.lstrip().startswith("HIERARCHY"):
                    raise BVHError(path, len(lines), "not a BVH file: it does not start with HIERARCHY")
                started = True
            if line.strip().startswith("Frame Time"):
                break
            if len(lines) > MAX_HEADER_LINES:
                raise BVHError(path, len(lines), f"no 'Frame Time' line in the first {MAX_HEADER_LINES} lines")
        if not lines:
            raise BVHError(path, 1, "not a BVH file: it is empty")
        skeleton, n_frames, frame_time, first = _parse_header(lines, path)
    except BVHError as e:
        f.close()
        if e.problem.startswith("not a text file") and e.line == 1:  # a binary file: no line to name
            raise BVHError(path, None, e.problem) from None
        raise
    except BaseException:
        f.close()
        raise
    n_channels = sum(len(c) for c in skeleton.channels)

    def frames() -> Iterator[np.ndarray]:
        line_no, done, trailing_blank = first, 0, None
        with f:
            batch: list[str] = []
            rest = _lines(f, path, first + 1)
            for line in rest:
                line_no += 1
                if not line.strip():
                    trailing_blank = trailing_blank or line_no
                    continue
                if trailing_blank is not None:
                    raise BVHError(path, trailing_blank, "blank line inside the frame data")
                if done + len(batch) >= n_frames:
                    extra = 1 + sum(1 for more in rest if more.strip())  # count on, in bounded memory
                    raise BVHError(path, line_no, f"Frames says {n_frames}, found {n_frames + extra} frame lines")
                batch.append(line)
                if len(batch) == chunk:
                    yield _frame_values(batch, line_no - len(batch) + 1, n_channels, path)
                    done, batch = done + len(batch), []
            if batch:
                yield _frame_values(batch, line_no - len(batch) + 1, n_channels, path)
                done += len(batch)
        if done < n_frames:
            raise BVHError(path, line_no, f"truncated MOTION section: Frames says {n_frames}, found {done} frame lines")

    return Header(skeleton, n_frames, 1.0 / frame_time, path), frames()


def channel_values_ok(values: np.ndarray) -> np.ndarray:
    """Per channel value, whether it can be motion: finite and ``|value| < MAX_CHANNEL``."""
    return np.abs(values) < MAX_CHANNEL  # False for NaN too


def channel_problem(skeleton: Skeleton, values: np.ndarray) -> tuple[int, str] | None:
    """The first channel value ``[T, n_channels]`` that cannot be motion (NaN, infinite, or
    ``|value| >= MAX_CHANNEL``) as (frame row, "joint 'Hips' Xposition = 1e+30 is ..."), else
    None. The one check of values to stylise: files (``transfer``) and streams (the server)."""
    ok = channel_values_ok(values)
    if ok.all():
        return None
    row, column = (int(i) for i in np.argwhere(~ok)[0])
    joint, channel = [(name, c) for name, chans in zip(skeleton.names, skeleton.channels) for c in chans][column]
    value = values[row, column]
    problem = (
        "is not a finite number"
        if not np.isfinite(value)
        else f"= {value:.3g} is out of range (|value| < {MAX_CHANNEL:g})"
    )
    return row, f"joint {joint!r} {channel} {problem}"


def motion_from_channels(skeleton: Skeleton, values: np.ndarray, fps: float) -> Motion:
    """The motion of BVH channel values ``[T, n_channels]`` in the skeleton's layout (the
    angles as given are kept as ``euler_hint``)."""
    T, J = len(values), skeleton.n_joints
    rotations, positions, hint = np.empty((T, J, 4)), np.empty((T, J, 3)), np.empty((T, J, 3))
    _from_channels_kernel(
        np.ascontiguousarray(values, dtype=np.float64),
        skeleton.offsets,
        *skeleton.channel_layout,
        skeleton.euler_axes,
        rotations,
        positions,
        hint,
    )
    return Motion(skeleton, rotations, positions, fps, euler_hint=hint)


@nb.njit(cache=True)
def _from_channels_kernel(
    values, offsets, pos_col, pos_joint, pos_axis, rot_col, rot_joint, rot_slot, axes, rotations, positions, hint
):
    for t in range(values.shape[0]):
        positions[t] = offsets  # a joint without position channels holds its rest offset
        hint[t] = 0.0
        for i in range(len(pos_col)):
            positions[t, pos_joint[i], pos_axis[i]] = values[t, pos_col[i]]
        for i in range(len(rot_col)):
            hint[t, rot_joint[i], rot_slot[i]] = values[t, rot_col[i]]
        for j in range(axes.shape[0]):  # scalars, not np.radians of a row: no array made per joint
            rotations[t, j, 0], rotations[t, j, 1], rotations[t, j, 2], rotations[t, j, 3] = quat.euler_scalars_to_quat(
                np.radians(hint[t, j, 0]),
                np.radians(hint[t, j, 1]),
                np.radians(hint[t, j, 2]),
                axes[j, 0],
                axes[j, 1],
                axes[j, 2],
            )


def read(path: str | os.PathLike) -> Motion:
    """A whole BVH file (read through ``stream``: the same checks, bounded lines)."""
    header, frames = stream(path)
    values = np.concatenate([np.zeros((0, sum(len(c) for c in header.skeleton.channels))), *frames])
    return motion_from_channels(header.skeleton, values, header.fps)


def channel_values(motion: Motion) -> np.ndarray:
    """The BVH channel values ``[T, n_channels]`` of a motion, in its skeleton's layout.
    Euler angles follow ``motion.euler_hint`` where there is one (the source file's branches),
    else they are unrolled over time so the curves have no +-180 degree flips."""
    sk, T = motion.skeleton, motion.n_frames
    pos_col, _, _, rot_col, _, _ = sk.channel_layout
    hint = (
        np.zeros((0, 0, 3)) if motion.euler_hint is None else np.ascontiguousarray(motion.euler_hint, dtype=np.float64)
    )
    angles, out = np.empty((T, sk.n_joints, 3)), np.empty((T, len(pos_col) + len(rot_col)))
    _euler_angles_kernel(np.ascontiguousarray(motion.rotations, dtype=np.float64), sk.euler_axes, hint, angles)
    if motion.euler_hint is None:
        angles = quat.unroll_euler(angles)
    _to_channels_kernel(np.ascontiguousarray(motion.positions, dtype=np.float64), angles, *sk.channel_layout, out)
    return out


@nb.njit(cache=True)
def _euler_angles_kernel(rotations, axes, hint, angles):
    """Euler angles (radians) of every joint in its order; nearest ``hint`` (degrees) where
    one is given, else the principal triple."""
    for t in range(rotations.shape[0]):
        for j in range(rotations.shape[1]):
            a0, a1, a2 = quat.quat_scalars_to_euler(
                rotations[t, j, 0],
                rotations[t, j, 1],
                rotations[t, j, 2],
                rotations[t, j, 3],
                axes[j, 0],
                axes[j, 1],
                axes[j, 2],
            )
            if hint.shape[0]:  # scalars: no array made per joint
                a0, a1, a2 = quat.nearest_euler_scalars(
                    a0, a1, a2, np.radians(hint[t, j, 0]), np.radians(hint[t, j, 1]), np.radians(hint[t, j, 2])
                )
            angles[t, j, 0], angles[t, j, 1], angles[t, j, 2] = a0, a1, a2


@nb.njit(cache=True)
def _to_channels_kernel(positions, angles, pos_col, pos_joint, pos_axis, rot_col, rot_joint, rot_slot, out):
    for t in range(positions.shape[0]):
        for i in range(len(pos_col)):
            out[t, pos_col[i]] = positions[t, pos_joint[i], pos_axis[i]]
        for i in range(len(rot_col)):
            out[t, rot_col[i]] = np.degrees(angles[t, rot_joint[i], rot_slot[i]])


def format_header(skeleton: Skeleton, n_frames: int, fps: float, precision: int = 9) -> str:
    """HIERARCHY and the MOTION header, up to and including the 'Frame Time' line."""
    sk = skeleton
    out = ["HIERARCHY"]
    ends: dict[int, list[np.ndarray]] = {}
    for j, o in sk.end_sites:
        ends.setdefault(j, []).append(o)

    def fmt3(v: np.ndarray) -> str:
        return " ".join(f"{x:.{precision}g}" for x in v)

    def joint(j: int, depth: int) -> None:
        pad = "\t" * depth
        out.append(f"{pad}{'ROOT' if depth == 0 else 'JOINT'} {sk.names[j]}")
        out.append(f"{pad}{{")
        out.append(f"{pad}\tOFFSET {fmt3(sk.offsets[j])}")
        if sk.channels[j]:
            out.append(f"{pad}\tCHANNELS {len(sk.channels[j])} {' '.join(sk.channels[j])}")
        for c in sk.children(j):
            joint(c, depth + 1)
        for o in ends.get(j, []):
            out.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {fmt3(o)}", f"{pad}\t}}"])
        out.append(f"{pad}}}")

    joint(0, 0)
    out += ["MOTION", f"Frames: {n_frames}", f"Frame Time: {1.0 / fps:.9g}"]
    return "\n".join(out) + "\n"


def format_frames(values: np.ndarray, precision: int = 9) -> str:
    """Frame lines of channel values ``[T, n_channels]``."""
    if values.shape[1] == 0:
        return "\n" * len(values)
    row = " ".join([f"%.{precision}g"] * values.shape[1])
    return "".join(row % tuple(v) + "\n" for v in values.tolist())


def format_bvh(motion: Motion, precision: int = 9) -> str:
    """The whole BVH text of ``motion`` (hierarchy and frames), angles to ``precision`` digits."""
    return format_header(motion.skeleton, motion.n_frames, motion.fps, precision) + format_frames(
        channel_values(motion), precision
    )


def write(path: str | os.PathLike, motion: Motion, precision: int = 9) -> None:
    """Write ``motion`` as a BVH file at ``path``, atomically: the file is complete or absent."""
    text = format_bvh(motion, precision)  # format fully before touching the file system
    atomic_write_text(path, text)
