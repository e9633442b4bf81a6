"""VMC bridge: Unity's left-handed axes both ways, bones in -> stylised bones out, over UDP."""

import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder
from pythonosc.osc_packet import OscPacket
from scipy.spatial.transform import Rotation

from styleerd.errors import StyleERDError
from styleerd.model.checkpoint import load_generator
from styleerd.motion import quat
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.procedural import walk
from styleerd.runtime.channels import ChannelStylizer
from styleerd.runtime.cleanup import FootLock
from styleerd.serve.vmc import (
    BONE,
    ROOT,
    VMCBridge,
    humanoid_skeleton,
    rotation_to_unity,
    unity_position,
    unity_rotation,
)

MIRROR = np.diag([-1.0, 1.0, 1.0])
UNITY_NAMES = {
    "Spine1": "Chest",
    "Spine2": "UpperChest",
    "LeftArm": "LeftUpperArm",
    "LeftForeArm": "LeftLowerArm",
    "LeftUpLeg": "LeftUpperLeg",
    "LeftLeg": "LeftLowerLeg",
    "LeftToeBase": "LeftToes",
}
UNITY_NAMES |= {k.replace("Left", "Right"): v.replace("Left", "Right") for k, v in UNITY_NAMES.items() if "Left" in k}


def test_axes_round_trip_and_match_a_mirrored_rotation():
    rng = np.random.default_rng(0)
    q_unity = Rotation.random(50, random_state=1).as_quat()  # x, y, z, w
    p = rng.normal(size=(50, 3))
    assert np.allclose(rotation_to_unity(unity_rotation(q_unity)), q_unity)
    assert np.allclose(unity_position(unity_position(p)), p)
    ours = unity_rotation(q_unity)
    R = Rotation.from_quat(np.concatenate([ours[:, 1:], ours[:, :1]], -1)).as_matrix()
    assert np.allclose(
        R, MIRROR @ Rotation.from_quat(q_unity).as_matrix() @ MIRROR
    )  # the same rotation seen in a mirror


def test_forward_kinematics_commutes_with_the_conversion():
    """Posing in Unity's axes then converting equals converting the local pose then posing."""
    m = walk(0.5, fps=30.0)
    rot_u = rotation_to_unity(m.rotations)  # treat the walk's numbers as a Unity pose
    pos_u = m.positions
    _g_rot_u, _g_pos_u = forward_kinematics(quat.normalize(unity_rotation(rot_u)), pos_u, m.skeleton.parents)
    _, g_pos_r = forward_kinematics(quat.normalize(unity_rotation(rot_u)), unity_position(pos_u), m.skeleton.parents)
    # positions in Unity axes from Unity-convention locals: x-mirror of the right-handed result
    R_u = Rotation.from_quat(rot_u.reshape(-1, 4)).as_matrix().reshape(*rot_u.shape[:2], 3, 3)
    P = np.zeros_like(pos_u)
    G = np.zeros_like(R_u)
    for j, parent in enumerate(m.skeleton.parents):
        if parent < 0:
            G[:, j], P[:, j] = R_u[:, j], pos_u[:, j]
        else:
            G[:, j] = G[:, parent] @ R_u[:, j]
            P[:, j] = P[:, parent] + np.einsum("tij,tj->ti", G[:, parent], pos_u[:, j])
    assert np.allclose(unity_position(P), g_pos_r, atol=1e-6)


def _unity_frames(seconds: float = 3.0, bundled: bool = True):
    """A procedural walk as a VMC Performer sends it: Unity names, metres, left-handed."""
    m = walk(seconds, fps=30.0)
    names = [UNITY_NAMES.get(n, n) for n in m.skeleton.names]
    frames = []
    for t in range(m.n_frames):
        msgs = [(ROOT, ["root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])]
        for j, name in enumerate(names):
            p = unity_position(m.positions[t, j] / 100.0)
            q = rotation_to_unity(m.rotations[t, j])
            msgs.append((BONE, [name, *map(float, p), *map(float, q)]))
        msgs.append(("/VMC/Ext/OK", [1]))
        built = []
        for address, params in msgs:
            b = OscMessageBuilder(address)
            for v in params:
                b.add_arg(v)
            built.append(b.build())
        if bundled:
            bundle = OscBundleBuilder(IMMEDIATELY)
            for msg in built:
                bundle.add_content(msg)
            frames.append([bundle.build().dgram])
        else:
            frames.append([msg.dgram for msg in built])
    return m, names, frames


@pytest.fixture(scope="module")
def model():
    return load_generator()[0]


def _decode(datagrams):
    """-> list of frames, each {bone: (position, quaternion xyzw)}, and the other addresses."""
    frames, others = [], []
    for d in datagrams:
        msgs = [x.message for x in OscPacket(d).messages]
        bones = {m.params[0]: (np.array(m.params[1:4]), np.array(m.params[4:8])) for m in msgs if m.address == BONE}
        if bones:
            frames.append(bones)
        others += [m.address for m in msgs if m.address not in (BONE, ROOT)]
    return frames, others


@pytest.mark.parametrize("bundled", [True, False])
def test_bridge_stylises_every_frame_keeps_positions_and_passes_other_messages(model, bundled):
    m, names, frames = _unity_frames(bundled=bundled)
    bridge = VMCBridge(model, {"elderly": 1.0}, report=lambda _: None)
    sent = [out for datagrams in frames for d in datagrams for out in bridge.feed(d)]
    got, others = _decode(sent)
    assert len(got) == m.n_frames and others.count("/VMC/Ext/OK") == m.n_frames
    assert set(got[0]) == set(names) and len(humanoid_skeleton({n: np.zeros(3) for n in names}).names) == len(names)
    hips = np.stack([f["Hips"][0] for f in got])
    given = unity_position(m.positions[:, 0] / 100.0)
    assert np.allclose(hips[:, [0, 2]], given[:, [0, 2]], atol=1e-5)  # the root's path kept; its height but for
    assert np.abs(hips[:, 1] - given[:, 1]).max() <= FootLock(m.skeleton).max_drop / 100.0 + 1e-5  # the feet's pelvis
    q = np.stack([np.stack([f[n][1] for n in names]) for f in got])
    assert np.isfinite(q).all() and np.allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-4)
    change = np.degrees(quat.angle_between(unity_rotation(q), m.rotations))  # styled, not copied
    assert change[:, names.index("LeftUpperArm")].mean() > 2.0


def test_bridge_with_tracked_arms_keeps_them_and_stylises_the_rest(model):
    """``--parts arms=input``: a VTuber's tracked arms come back as they went in."""
    m, names, frames = _unity_frames(bundled=True)
    bridge = VMCBridge(model, {"elderly": 1.0}, report=lambda _: None, parts="arms=input")
    got, _ = _decode([out for datagrams in frames for d in datagrams for out in bridge.feed(d)])
    q = unity_rotation(np.stack([np.stack([f[n][1] for n in names]) for f in got]))
    change = np.degrees(quat.angle_between(q, m.rotations))
    arms = [names.index(n) for n in ("LeftUpperArm", "LeftLowerArm", "RightUpperArm", "RightLowerArm")]
    assert change[:, arms].max() < 0.1, change[:, arms].max()
    assert change[:, names.index("LeftUpperLeg")].mean() > 2.0  # the legs are stylised
    with pytest.raises(StyleERDError, match="unknown body part 'hands'"):
        VMCBridge(model, {"elderly": 1.0}, parts="hands=input")


def test_bridge_with_root_speed_moves_the_hips_at_the_styles_pace(model):
    """``--root-speed``: the hips sent are the stylised ones, as a local stylizer with root
    speed gives them on the same frames; the other bones' positions stay the avatar's."""
    m, names, frames = _unity_frames(bundled=True)
    bridge = VMCBridge(model, {"elderly": 1.0}, report=lambda _: None, root_speed=True)
    got, _ = _decode([out for datagrams in frames for d in datagrams for out in bridge.feed(d)])
    hips = unity_position(np.stack([f["Hips"][0] for f in got]))
    sent, _ = _decode([d for datagrams in frames for d in datagrams])  # as received: float32
    sk = humanoid_skeleton({b: unity_position(p) for b, (p, _) in sent[0].items()})
    local = ChannelStylizer(model, sk, {"elderly": 1.0}, fps=30.0, root_speed=True)
    for t, bones in enumerate(sent):
        rot = quat.normalize(np.stack([unity_rotation(bones[b][1]) for b in sk.names]))
        pos = sk.offsets.copy()
        pos[0] = unity_position(bones["Hips"][0])
        expected = local.step_pose(Motion(sk, rot[None], pos[None], 30.0))
        assert np.allclose(hips[t], expected.positions[0, 0], atol=1e-5), t
    given = m.positions[:, 0] / 100.0
    assert np.abs(hips - given).max() > 0.01  # another pace
    assert abs(hips[:, 1].mean() - given[:, 1].mean()) < 0.02  # at the performer's height
    knee = np.stack([f["LeftLowerLeg"][0] for f in got])
    assert np.allclose(knee, unity_position(m.positions[:, names.index("LeftLowerLeg")] / 100.0), atol=1e-5)


def test_bridge_rejects_bad_frames_and_datagrams(model):
    _m, _names, frames = _unity_frames(1.0)
    bridge = VMCBridge(model, {"elderly": 1.0}, report=lambda _: None)
    assert bridge.feed(b"not osc at all") == [] and bridge.malformed == 1
    for datagrams in frames[:5]:
        for d in datagrams:
            bridge.feed(d)
    b = OscMessageBuilder(BONE)
    for v in ["Hips", float("nan"), 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]:
        b.add_arg(v)
    bundle = OscBundleBuilder(IMMEDIATELY)
    for d in [x.message for x in OscPacket(frames[5][0]).messages]:
        bundle.add_content(d if d.params[:1] != ["Hips"] else b.build())
    before = bridge.frames
    bridge.feed(bundle.build().dgram)
    assert bridge.malformed == 2 and bridge.frames == before  # the NaN bone is dropped: never kept, never sent
    for datagrams in frames[6:9]:
        for d in datagrams:
            bridge.feed(d)
    assert bridge.frames == before + 3  # the next frames go on


def test_vmc_command_over_udp():
    def port():
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]

    listen, send = port(), port()
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)  # read after sending: keep every reply
    rx.bind(("127.0.0.1", send))
    rx.settimeout(30)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "styleerd.cli",
            "vmc",
            "--listen",
            str(listen),
            "--send",
            str(send),
            "--style",
            "feminine",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        m, names, frames = _unity_frames(2.0)
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        received = []
        assert "receiving VMC" in proc.stdout.readline()  # the bridge has loaded its model and listens
        for t, datagrams in enumerate(frames):
            for d in datagrams:
                tx.sendto(d, ("127.0.0.1", listen))
            if t == 1:  # the second frame completes the first: the bridge sets up the avatar
                assert "VMC: 22 bones" in proc.stdout.readline()
            time.sleep(1 / 30)
        deadline = time.time() + 20
        while time.time() < deadline:
            received.append(rx.recv(65536))
            if len(_decode(received)[0]) == m.n_frames:
                break
        got, _ = _decode(received)
        assert len(got) == m.n_frames and set(got[-1]) == set(names)
    finally:
        proc.terminate()
        proc.communicate(timeout=10)
        rx.close()


def _osc(address, *args) -> bytes:
    b = OscMessageBuilder(address)
    for v in args:
        b.add_arg(v)
    return b.build().dgram


def _double(address, name, *numbers) -> bytes:
    """A message whose numbers are OSC doubles ('d'): values float32 cannot hold."""
    b = OscMessageBuilder(address)
    b.add_arg(name)
    for v in numbers:
        b.add_arg(v, "d")
    return b.build().dgram


def _nested(depth: int) -> bytes:
    """A bundle inside a bundle, ``depth`` deep (raw bytes: the builder would recurse as deep)."""
    import struct

    inner = _osc("/VMC/Ext/OK", 1)
    for _ in range(depth):
        inner = b"#bundle\0" + struct.pack(">Q", 1) + struct.pack(">i", len(inner)) + inner
    return inner


GOOD_BONE = ["Hips", 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
# the bad datagrams of issue 36's VMC list, and more of each kind
BAD_DATAGRAMS = {
    "empty": b"",
    "not OSC": b"not osc at all",
    "truncated message": _osc(BONE, *GOOD_BONE)[:13],
    "a string where a float belongs": _osc(BONE, "Hips", "1.0", 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    "the bone name as a number": _osc(BONE, 5, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    "the bone name as an OSC array": _osc(BONE, ["Hips"], 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    "a position as an array": _osc(BONE, "Hips", [0.0, 1.0, 0.0], 0.0, 0.0, 0.0, 1.0),
    "too few arguments": _osc(BONE, "Hips", 0.0, 1.0),
    "a root with too few arguments": _osc(ROOT, "root", 0.0),
    "NaN position": _osc(BONE, "Hips", float("nan"), 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    "infinite rotation": _osc(BONE, "Hips", 0.0, 1.0, 0.0, float("inf"), 0.0, 0.0, 1.0),
    "a double that overflows float32": _double(BONE, "Hips", 1e39, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    "a double of 1e308": _double(BONE, "Hips", 0.0, 1.0, 0.0, 1e308, 0.0, 0.0, 1.0),
    "a position of 1e30 (garbage)": _osc(BONE, "Hips", 1e30, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    "a zero quaternion": _osc(BONE, "Hips", 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    "booleans for numbers": _osc(BONE, "Hips", True, False, True, False, True, False, True),
    "a blob argument": _osc(BONE, "Hips", b"\x00\x01", 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    "a timetag argument": b"/VMC/Ext/Bone/Pos\0\0\0,st\0Hips\0\0\0\0" + bytes(8),
    "an unknown type tag": b"/VMC/Ext/Bone/Pos\0\0\0,sz\0Hips\0\0\0\0",
    "a non-UTF-8 address": b"/VMC/\xff\xfe\0\0,\0\0\0",
    "a non-UTF-8 bone name": b"/VMC/Ext/Bone/Pos\0\0\0,s\0\0\xff\xfe\0\0",
    "1,500 nested bundles": _nested(1500),
    "a bundle whose size lies": b"#bundle\0" + bytes(8) + b"\x7f\xff\xff\xff" + _osc("/x", 1),
    "a bone name of 10,000 characters": _osc(BONE, "H" * 10_000, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    "an unknown bone": _osc(BONE, "Tail", 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
    "64 KB of junk": bytes(range(256)) * 256,
}


@pytest.mark.parametrize("kind", BAD_DATAGRAMS)
def test_a_bad_datagram_is_dropped_and_the_stream_goes_on(model, kind):
    """Before and after the skeleton is set up: no exception, nothing non-finite sent, and the
    next good frames are stylised."""
    _m, _names, frames = _unity_frames(0.5)
    bridge = VMCBridge(model, {"elderly": 1.0}, report=lambda _: None)
    sent = bridge.feed(BAD_DATAGRAMS[kind])
    for t, datagrams in enumerate(frames):
        for d in datagrams:
            sent += bridge.feed(d)
        if t == 5:
            sent += bridge.feed(BAD_DATAGRAMS[kind])
    got, _ = _decode(sent)
    assert len(got) >= len(frames) - 2 and all(
        np.isfinite(np.concatenate([np.concatenate(v) for v in f.values()])).all() for f in got
    )


@pytest.mark.parametrize("examples", [300, pytest.param(10_000, marks=pytest.mark.slow, id="long")])
def test_fuzzed_datagrams_never_stop_the_bridge(model, examples):
    """Random OSC messages (any argument types on the VMC addresses) and random bytes; the long run
    (10,000 datagrams) is marked slow; CI runs it."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    _m, names, frames = _unity_frames(0.3)
    bridge = VMCBridge(model, {"elderly": 1.0}, report=lambda _: None)
    for datagrams in frames:
        for d in datagrams:
            bridge.feed(d)
    args = st.one_of(
        st.floats(allow_nan=True, allow_infinity=True, width=32),
        st.integers(-(2**31), 2**31 - 1),
        st.text(max_size=8),
        st.booleans(),
        st.binary(min_size=1, max_size=8),
        st.sampled_from(names),
    )

    def built(address, xs) -> bytes:
        try:
            return _osc(address, *xs)
        except Exception:  # noqa: BLE001  python-osc cannot build it (it re-parses what it built): not something a sender sends
            return b""

    messages = st.builds(built, st.sampled_from([ROOT, BONE, "/VMC/Ext/OK"]), st.lists(args, max_size=10))

    @settings(max_examples=examples, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
    @given(st.one_of(messages, st.binary(max_size=200)))
    def run(datagram):
        for out in bridge.feed(datagram):
            for x in OscPacket(out).messages:
                if x.message.address in (ROOT, BONE):  # other messages pass on as they came
                    assert all(np.isfinite(v) for v in x.message.params if isinstance(v, float))

    run()
    before = bridge.frames
    for datagrams in frames:
        for d in datagrams:
            bridge.feed(d)
    assert bridge.frames > before


def test_a_first_frame_without_hips_waits_and_a_new_avatar_is_mapped_again(model):
    """A first frame without Hips is dropped (it stopped the bridge); after the performer switches to
    an avatar without UpperChest (no frame was sent again), the new bones are mapped after a few
    frames and frames flow again."""
    _m, _names, frames = _unity_frames(1.0)
    reports = []
    bridge = VMCBridge(model, {"elderly": 1.0}, report=reports.append)
    no_hips = [
        _osc(ROOT, "root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
        _osc(BONE, "Spine", 0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 1.0),
    ]
    for d in no_hips + no_hips:
        assert bridge.feed(d) == [] or True
    assert any("no 'Hips' bone" in r for r in reports)
    sent = []
    for datagrams in frames[:10]:
        for d in datagrams:
            sent += bridge.feed(d)
    first = len(_decode(sent)[0])
    assert first >= 8
    # the new avatar: no UpperChest (its children hang from Chest)
    without = []
    for datagrams in frames[10:]:
        msgs = [x.message for d in datagrams for x in OscPacket(d).messages]
        bundle = OscBundleBuilder(IMMEDIATELY)
        for msg in msgs:
            if msg.params[:1] != ["UpperChest"]:
                bundle.add_content(msg)
        without.append(bundle.build().dgram)
    sent = [out for d in without for out in bridge.feed(d)]
    got, _ = _decode(sent)
    assert bridge.remapped == 1 and any("bones changed" in r for r in reports)
    assert len(got) >= len(without) - 5 and "UpperChest" not in got[-1] and "Chest" in got[-1]


def test_vmc_refuses_to_send_where_it_listens():
    done = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "vmc", "--listen", "39539", "--send", "39539", "--style", "elderly"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 2 and "would receive what it sends" in done.stderr and "Traceback" not in done.stderr
