import string
import subprocess
import sys

import numpy as np
import pytest
from conftest import walking_motion
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from styleerd.motion import bvh, quat
from styleerd.motion.bvh import BVHError
from styleerd.motion.kinematics import forward_kinematics

# ---------------------------------------------------------------- generated files


@st.composite
def bvh_files(draw):
    """BVH text for a random hierarchy and channel layout, plus the channel values in it."""
    n = draw(st.integers(1, 7))
    parents = [-1] + [draw(st.integers(0, j - 1)) for j in range(1, n)]
    names = draw(
        st.lists(
            st.text(string.ascii_letters + string.digits + "_:", min_size=1, max_size=10),
            min_size=n,
            max_size=n,
            unique=True,
        )
    )
    channels = []
    for j in range(n):
        rot = [f"{a}rotation" for a in draw(st.permutations("XYZ"))][: draw(st.sampled_from([3, 3, 2, 1, 0]))]
        pos = [f"{a}position" for a in draw(st.permutations("XYZ"))][: draw(st.sampled_from([0, 3, 3, 1]))]
        channels.append(pos + rot if draw(st.booleans()) else rot + pos)
    finite = st.floats(-200, 200, allow_nan=False, width=32)
    offsets = [[draw(finite) for _ in range(3)] for _ in range(n)]
    T = draw(st.integers(0, 4))
    rows = []
    for _ in range(T):
        row = []
        for chans in channels:
            rots = [c for c in chans if c.endswith("rotation")]
            a, b, c = draw(st.floats(-180, 180)), draw(st.floats(-89, 89)), draw(st.floats(-180, 180))
            if len(rots) == 3 and draw(st.booleans()):  # the other, equivalent triple
                a, b, c = a + 180, 180 - b, c + 180
            angles = iter(
                np.array([a, b, c]) + 360 * np.array([draw(st.integers(-1, 1)) for _ in range(3)])
                if len(rots) == 3
                else [a, b, c]
            )
            for ch in chans:
                row.append(next(angles) if ch.endswith("rotation") else draw(finite))
        rows.append(row)
    leaves = [j for j in range(n) if j not in parents]
    sep = draw(st.sampled_from(["\t", "  ", " "]))
    trailing = draw(st.sampled_from(["", " ", "\t"]))

    lines = ["HIERARCHY"]

    def joint(j, depth):
        pad = sep * depth
        lines.append(f"{pad}{'ROOT' if j == 0 else 'JOINT'} {names[j]}{trailing}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}{sep}OFFSET {' '.join(repr(x) for x in offsets[j])}")
        if channels[j] or draw(st.booleans()):
            lines.append(f"{pad}{sep}CHANNELS {len(channels[j])} {' '.join(channels[j])}{trailing}")
        for c in range(n):
            if parents[c] == j:
                joint(c, depth + 1)
        if j in leaves:
            lines.extend([f"{pad}{sep}End Site", f"{pad}{sep}{{", f"{pad}{sep}{sep}OFFSET 0 1.5 0", f"{pad}{sep}}}"])
        lines.append(f"{pad}}}")

    joint(0, 0)
    lines += [
        "MOTION",
        f"Frames: {T}",
        f"Frame Time: {draw(st.sampled_from(['0.0333333', '0.008333', '0.1', '0.00208333']))}",
    ]
    lines += [" ".join(repr(float(v)) for v in row) + trailing for row in rows]
    newline = draw(st.sampled_from(["\n", "\r\n"]))
    return newline.join(lines) + newline, np.array(rows, dtype=np.float64).reshape(T, sum(len(c) for c in channels))


def fk(m):
    return forward_kinematics(m.rotations, m.positions, m.skeleton.parents)[1]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(bvh_files())
def test_read_write_read_is_lossless_on_random_layouts(case):
    text, values = case
    m = bvh.parse(text)
    assert m.n_frames == len(values)
    got = bvh.channel_values(m)
    assert np.allclose(got, values, rtol=1e-9, atol=1e-9)
    m2 = bvh.parse(bvh.format_bvh(m))
    assert m2.skeleton == m.skeleton
    assert [j for j, _ in m2.skeleton.end_sites] == [j for j, _ in m.skeleton.end_sites]
    assert np.isclose(m2.fps, m.fps, rtol=1e-8)
    assert np.allclose(bvh.channel_values(m2), values, rtol=1e-5, atol=1e-5)
    assert np.allclose(fk(m2), fk(m), atol=1e-4)


def test_channel_values_without_hint_are_continuous():
    m = walking_motion(90)
    m.rotations[:, 0] = quat.mul(
        quat.from_angle_axis(np.linspace(0, 6 * np.pi, 90), np.array([0, 1.0, 0])), m.rotations[:, 0]
    )
    values = bvh.channel_values(m)
    assert np.abs(np.diff(values[:, 3:], axis=0)).max() < 60  # no +-360 jumps
    back = bvh.parse(bvh.format_bvh(m))
    assert np.allclose(fk(back), fk(m), atol=1e-4)


def test_write_is_atomic_and_file_roundtrips(tmp_path):
    m = walking_motion(12)
    out = tmp_path / "w.bvh"
    bvh.write(out, m)
    assert np.allclose(fk(bvh.read(out)), fk(m), atol=1e-4)
    assert [p.name for p in tmp_path.iterdir()] == ["w.bvh"]


def test_zero_and_one_frame_files():
    m = walking_motion(1)
    one = bvh.parse(bvh.format_bvh(m))
    assert one.n_frames == 1
    zero = bvh.parse(bvh.format_bvh(m[:0]))
    assert zero.n_frames == 0 and zero.skeleton == m.skeleton


# ---------------------------------------------------------------- bad input

GOOD = """HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT Leg
\t{
\t\tOFFSET 0 -10 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 -10 0
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 90 0 0 0 0 10 20 30
1 90 0 0 0 0 11 21 31
"""


def test_good_file_parses():
    m = bvh.parse(GOOD)
    assert m.n_frames == 2 and m.skeleton.names == ("Hips", "Leg")


BAD = {
    "missing brace": (GOOD.replace("\t}\n}\nMOTION", "\t}\nMOTION"), 15, "missing '}'"),
    "wrong number of values": (GOOD.replace("11 21 31", "11 21"), 20, "8 values, the hierarchy declares 9"),
    "non-numeric token": (GOOD.replace("11 21 31", "11 abc 31"), 20, "'abc' is not a number"),
    "truncated motion": (GOOD.replace("1 90 0 0 0 0 11 21 31\n", ""), 19, "truncated MOTION section"),
    "unknown channel": (
        GOOD.replace("3 Zrotation Xrotation Yrotation", "3 Zrotation Xrotation Wrotation"),
        9,
        "unknown channel name 'Wrotation'",
    ),
    "duplicate joint": (GOOD.replace("JOINT Leg", "JOINT Hips"), 6, "duplicate joint name 'Hips'"),
    "nan value": (GOOD.replace("10 20 30", "10 nan 30"), 19, "'nan' of channel 7 is not finite"),
    "inf value": (GOOD.replace("11 21 31", "inf 21 31"), 20, "'inf' of channel 6 is not finite"),
    "frames count disagrees": (GOOD.replace("Frames: 2", "Frames: 1"), 20, "Frames says 1, found 2 frame lines"),
    "huge offset": (  # finite, but a joint 1e300 units away overflowed the kinematics into a written file
        GOOD.replace("OFFSET 0 -10 0\n\t\tCHANNELS", "OFFSET 0 -1e300 0\n\t\tCHANNELS"),
        8,
        "joint 'Leg' OFFSET: -1e300 is out of range",
    ),
    "huge end site": (GOOD.replace("\t\t\tOFFSET 0 -10 0", "\t\t\tOFFSET 0 -10 1e7"), 12, "1e7 is out of range"),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_input_raises_one_bvh_error_naming_file_line_and_problem(case):
    text, line, problem = BAD[case]
    with pytest.raises(BVHError) as err:
        bvh.parse(text, "bad.bvh")
    assert err.value.line == line, str(err.value)
    assert problem in err.value.problem
    assert str(err.value).startswith(f"bad.bvh:{line}: ")


@pytest.mark.parametrize("case", BAD)
def test_cli_prints_one_line_exits_2_and_writes_nothing(case, tmp_path):
    src = tmp_path / "bad.bvh"
    src.write_text(BAD[case][0])
    out = tmp_path / "out.bvh"
    r = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "resample", str(src), "--fps", "60", "-o", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 2
    assert r.stdout == "" and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"bad.bvh:{BAD[case][1]}:" in r.stderr
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == ["bad.bvh"]


def test_not_a_bvh_file(tmp_path):
    p = tmp_path / "x.bvh"
    p.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    with pytest.raises(BVHError, match="not a"):
        bvh.read(p)
    with pytest.raises(BVHError, match="No such file"):
        bvh.read(tmp_path / "missing.bvh")


@pytest.mark.parametrize("case", BAD)
def test_streamed_reading_reports_the_same_problems(case, tmp_path):
    text, line, problem = BAD[case]
    (tmp_path / "bad.bvh").write_text(text)
    with pytest.raises(BVHError) as err:
        _header, frames = bvh.stream(tmp_path / "bad.bvh", chunk=1)
        for _ in frames:
            pass
    assert err.value.line == line and problem in err.value.problem, str(err.value)


@pytest.mark.parametrize("chunk", [1, 2, 3, 1000])
def test_streamed_reading_gives_the_same_values(tmp_path, chunk):
    m = walking_motion(7)
    bvh.write(tmp_path / "m.bvh", m)
    header, frames = bvh.stream(tmp_path / "m.bvh", chunk)
    whole = bvh.read(tmp_path / "m.bvh")
    assert header.skeleton == whole.skeleton and header.n_frames == 7 and np.isclose(header.fps, whole.fps)
    assert np.allclose(np.concatenate(list(frames)), bvh.channel_values(whole), rtol=0, atol=1e-9)


def test_a_byte_order_mark_and_leading_blank_lines_are_read(tmp_path):
    (tmp_path / "bom.bvh").write_text("\n\n" + GOOD, encoding="utf-8-sig")
    assert bvh.read(tmp_path / "bom.bvh").n_frames == 2
