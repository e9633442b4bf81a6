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
from styleerd.runtime.channels import ChannelStylizer
from styleerd.motion import quat
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.procedural import walk
from styleerd.serve.vmc import BONE, ROOT, VMCBridge, humanoid_skeleton, rotation_to_unity, unity_position, unity_rotation

MIRROR = np.diag([-1.0, 1.0, 1.0])
UNITY_NAMES = {"Spine1": "Chest", "Spine2": "UpperChest", "LeftArm": "LeftUpperArm", "LeftForeArm": "LeftLowerArm", "LeftUpLeg": "LeftUpperLeg",
               "LeftLeg": "LeftLowerLeg", "LeftToeBase": "LeftToes"}  # fmt: skip
UNITY_NAMES |= {k.replace("Left", "Right"): v.replace("Left", "Right") for k, v in UNITY_NAMES.items() if "Left" in k}


def test_axes_round_trip_and_match_a_mirrored_rotation():
    rng = np.random.default_rng(0)
    q_unity = Rotation.random(50, random_state=1).as_quat()  # x, y, z, w
    p = rng.normal(size=(50, 3))
    assert np.allclose(rotation_to_unity(unity_rotation(q_unity)), q_unity)
    assert np.allclose(unity_position(unity_position(p)), p)
    ours = unity_rotation(q_unity)
    R = Rotation.from_quat(np.concatenate([ours[:, 1:], ours[:, :1]], -1)).as_matrix()
    assert np.allclose(R, MIRROR @ Rotation.from_quat(q_unity).as_matrix() @ MIRROR)  # the same rotation seen in a mirror


def test_forward_kinematics_commutes_with_the_conversion():
    """Posing in Unity's axes then converting equals converting the local pose then posing."""
    m = walk(0.5, fps=30.0)
    rot_u = rotation_to_unity(m.rotations)  # treat the walk's numbers as a Unity pose
    pos_u = m.positions
    g_rot_u, g_pos_u = forward_kinematics(quat.normalize(unity_rotation(rot_u)), pos_u, m.skeleton.parents)
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
    assert np.allclose(hips, unity_position(m.positions[:, 0] / 100.0), atol=1e-5)  # root trajectory kept
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
    m, names, frames = _unity_frames(1.0)
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
    assert bridge.rejected == 1 and bridge.frames == before


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
    proc = subprocess.Popen([sys.executable, "-m", "styleerd.cli", "vmc", "--listen", str(listen), "--send", str(send), "--style", "feminine"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
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
