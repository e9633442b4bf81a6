import numpy as np
import pytest
import torch
from conftest import walking_motion

from styleerd.data.features import FeatureStats, motion_features
from styleerd.model import checkpoint as ckpt
from styleerd.model import torch_quat
from styleerd.model.classifiers import WindowClassifier
from styleerd.model.discriminator import Discriminator
from styleerd.model.generator import GeneratorConfig, StyleERD
from styleerd.motion import quat
from styleerd.motion.kinematics import forward_kinematics

STYLES = ("angry", "normal", "old", "proud")
CONTENTS = ("walk", "run")


@pytest.fixture(scope="module")
def setup():
    m = walking_motion(120)
    f, _ = motion_features(m)
    stats = FeatureStats.fit(f, m.skeleton.n_joints)
    torch.manual_seed(0)
    config = GeneratorConfig(m.skeleton.n_joints, STYLES, CONTENTS, neutral_layers=3, style_layers=2)
    model = StyleERD(config, m.skeleton, stats).eval()
    for p in model.parameters():  # learned initial states start at zero: make them matter
        p.data += 0.05 * torch.randn_like(p)
    x = torch.tensor(stats.normalize(f), dtype=torch.float32).reshape(4, 30, -1)
    return m, stats, model, x


def labels(model, style, content, target):
    eye_s, eye_c = torch.eye(len(STYLES)), torch.eye(len(CONTENTS))
    return eye_s[style], eye_c[content], target


def test_step_equals_forward_with_mixed_targets(setup):
    _, _, model, x = setup
    s, c, _ = labels(model, [0, 1, 2, 3], [0, 1, 1, 0], None)
    target = torch.tensor([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0.7, 0.3], [0, 0.4, 0.6, 0]])
    with torch.no_grad():
        rot, vel, _ = model(x, s, c, target)
        state = None
        for t in range(x.shape[1]):
            r, v, state = model.step(x[:, t], s, c, target, state)
            assert torch.allclose(r, rot[:, t], atol=1e-5) and torch.allclose(v, vel[:, t], atol=1e-5)
        # chunked forward with carried state == one forward
        r1, _v1, st = model(x[:, :13], s, c, target)
        r2, _v2, _ = model(x[:, 13:], s, c, target, st)
        assert torch.allclose(torch.cat([r1, r2], 1), rot, atol=1e-5)
    assert torch.allclose(rot.norm(dim=-1), torch.ones(()), atol=1e-5)


def test_forward_targets_equals_forward_on_the_repeated_batch(setup):
    """Training's reconstruction and transfer share the encoder and neutral branch: outputs
    and gradients equal those of one forward over the batch given twice."""
    _, _, model, x = setup
    s, c, _ = labels(model, [0, 1, 2, 3], [0, 1, 1, 0], None)
    targets = torch.cat([s, torch.tensor([[0, 1.0, 0, 0], [0, 0, 1, 0], [0, 0.4, 0.6, 0], [0, 1, 0, 0]])])
    grads = []
    for shared in (False, True):
        model.zero_grad()
        if shared:
            rot, vel = model.forward_targets(x, s, c, targets)
        else:
            rot, vel, _ = model(torch.cat([x, x]), torch.cat([s, s]), torch.cat([c, c]), targets)
        (rot.square().sum() + vel.sum()).backward()
        grads.append((rot.detach(), vel.detach(), [p.grad.clone() for p in model.parameters() if p.grad is not None]))
    (r1, v1, g1), (r2, v2, g2) = grads
    assert torch.allclose(r1, r2, atol=1e-5) and torch.allclose(v1, v2, atol=1e-5)
    assert len(g1) == len(g2) and all(torch.allclose(a, b, atol=1e-4, rtol=1e-4) for a, b in zip(g1, g2))
    model.zero_grad()


def test_output_is_causal(setup):
    _, _, model, x = setup
    s, c, _ = labels(model, [0, 1, 2, 3], [0, 1, 1, 0], None)
    with torch.no_grad():
        rot, vel, _ = model(x, s, c, s)
        x2 = x.clone()
        x2[:, 20:] += torch.randn_like(x2[:, 20:])
        rot2, vel2, _ = model(x2, s, c, s)
    assert torch.equal(rot[:, :20], rot2[:, :20]) and torch.equal(vel[:, :20], vel2[:, :20])
    assert not torch.allclose(rot[:, 20:], rot2[:, 20:])


def test_only_needed_branches_run(setup):
    _, _, model, x = setup
    calls = []
    hooks = [
        b.register_forward_hook(lambda mod, i, o, k=k: calls.append((k, i[0].shape[0])))
        for k, b in enumerate(model.branches)
    ]
    s, c, _ = labels(model, [1, 1, 1, 1], [0, 0, 0, 0], None)
    target = torch.eye(4)[[1, 1, 2, 2]]  # neutral, neutral, old, old
    with torch.no_grad():
        model(x, s, c, target)
    for h in hooks:
        h.remove()
    old = model.branch_styles.index(STYLES.index("old"))
    assert calls == [(old, 2)]  # one branch, on the two rows that need it


def test_learned_initial_state_selected_by_content(setup):
    _, _, model, _x = setup
    st = model.initial_state(torch.eye(2)[[0, 1]])
    assert torch.equal(st.neutral[0][:, 0], model.neutral_h0[0]) and torch.equal(
        st.neutral[0][:, 1], model.neutral_h0[1]
    )
    zero = StyleERD(
        GeneratorConfig(model.config.n_joints, STYLES, CONTENTS, learned_init=False),
        walking_motion(2).skeleton,
        setup[1],
    )
    assert not zero.neutral_h0.requires_grad and not zero.branch_h0.requires_grad


def test_motion_channels_of_input_rotations_reproduce_input_positions(setup):
    m, _stats, model, x = setup
    rot = model.raw_rotations(x)
    ch = model.motion_channels(rot, x[..., model.layout.velocities])
    J = m.skeleton.n_joints
    assert torch.allclose(ch, x[..., : 10 * J], atol=1e-3)


def test_torch_fk_and_quat_match_numpy():
    m = walking_motion(8)
    rot = torch.tensor(m.rotations)
    pos = torch_quat.root_relative_positions(rot, torch.tensor(m.skeleton.offsets), list(m.skeleton.parents))
    _, g = forward_kinematics(m.rotations, m.positions, m.skeleton.parents)
    assert np.allclose(pos.numpy(), g - g[:, :1], atol=1e-9)
    a, b = m.rotations[:, 3], m.rotations[:, 5]
    assert np.allclose(torch_quat.mul(torch.tensor(a), torch.tensor(b)).numpy(), quat.mul(a, b))
    loss = torch_quat.angle_loss(torch.tensor(a), torch.tensor(-a))
    assert loss.item() < 1e-5  # q and -q are the same rotation


def test_torch_fk_by_depth_matches_scipy_on_a_tree_in_any_order():
    """Joints listed in no depth order (a parent may come after its siblings' children), as a
    user's BVH may list them: positions against scipy's Rotation, gradients against finite differences."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    parents = [-1] + [int(rng.integers(0, j)) for j in range(1, 15)]
    offsets = rng.normal(size=(15, 3))
    q = rng.normal(size=(2, 5, 15, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    pos = torch_quat.root_relative_positions(torch.tensor(q), torch.tensor(offsets), parents).numpy()
    local = Rotation.from_quat(q[..., [1, 2, 3, 0]].reshape(-1, 4)).as_matrix().reshape(10, 15, 3, 3)
    glob, expected = [None] * 15, np.zeros((10, 15, 3))
    for j in range(15):  # parents come before children in this list
        p = parents[j]
        glob[j] = local[:, j] if p < 0 else glob[p] @ local[:, j]
        expected[:, j] = 0.0 if p < 0 else expected[:, p] + glob[p] @ offsets[j]
    assert np.allclose(pos.reshape(10, 15, 3), expected, atol=1e-12)
    x = torch.tensor(q[:1, :2], requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda r: torch_quat.root_relative_positions(r, torch.tensor(offsets), parents), (x,)
    )
    with pytest.raises(ValueError, match="one tree"):
        torch_quat.root_relative_positions(
            torch.tensor(q), torch.tensor(offsets), [-1, 0, 3, 2] + list(range(11))
        )  # 2, 3: a loop


def test_discriminator_attention_and_ablation_shapes():
    x = torch.randn(5, 24, 60)
    s, c = torch.eye(4)[[0, 1, 2, 3, 0]], torch.eye(2)[[0, 1, 0, 1, 0]]
    for attention in (True, False):
        d = Discriminator(60, 4, 2, 24, attention=attention)
        assert d(x, s, c).shape == (5,)
    d = Discriminator(60, 4, 2, 24, attention=True)
    d.feature_attention.bias.data += 1
    assert not torch.allclose(d(x, s, c), d(x, torch.eye(4)[[1, 2, 3, 0, 1]], c))  # labels steer the score


def test_checkpoint_roundtrip_without_pickle(setup, tmp_path):
    m, stats, model, x = setup
    ckpt.save_tensors(
        tmp_path / "g", ckpt.prefixed("generator", model), ckpt.generator_meta(model, m.skeleton, stats, note="x")
    )
    assert (tmp_path / "g.json").is_file() and b"pickle" not in (tmp_path / "g.safetensors").read_bytes()[:64]
    again, meta = ckpt.load_generator(tmp_path / "g")
    s, c, _ = labels(model, [0, 1, 2, 3], [0, 1, 1, 0], None)
    with torch.no_grad():
        assert torch.equal(again(x, s, c, s)[0], model(x, s, c, s)[0])
    assert meta["note"] == "x"
    cls = WindowClassifier(30, 3)
    ckpt.save_tensors(
        tmp_path / "c", ckpt.prefixed("style", cls), {"style": ckpt.classifier_meta(cls, ["a", "b", "c"])}
    )
    tensors, meta = ckpt.load_tensors(tmp_path / "c")
    rebuilt = ckpt.build_classifier(meta["style"])
    rebuilt.load_state_dict(ckpt.unprefixed("style", tensors))
    xx = torch.randn(2, 24, 30)
    assert torch.equal(rebuilt(xx), cls(xx))
