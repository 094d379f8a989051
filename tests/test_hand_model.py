"""HandModel on every built-in hand and on a third-party URDF with meshes: FK against MuJoCo,
couplings, deterministic clouds, labels."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch
from conftest import BUILTIN_HANDS

from lerobot_opfa.hands import HandModel, load_hand
from lerobot_opfa.hands.mujoco_model import hand_mjspec
from lerobot_opfa.hands.validate import coupling_limit_problems, fk_error_vs_mujoco


def _random_states(hand: HandModel, n: int = 16, seed: int = 0) -> torch.Tensor:
    return hand.sample_joints(n, torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("name", BUILTIN_HANDS)
def test_fk_matches_mujoco(name):
    hand = load_hand(name)
    position_error, rotation_error = fk_error_vs_mujoco(hand, _random_states(hand))
    assert position_error < 1e-5
    assert rotation_error < 1e-5


@pytest.mark.parametrize("name", BUILTIN_HANDS)
def test_couplings_honoured(name):
    hand = load_hand(name)
    q = _random_states(hand)
    q_all = hand.expand(q)
    assert torch.allclose(q_all[:, [hand.chain_joint_names.index(j) for j in hand.joint_names]], q)
    for coupling in hand.spec.couplings.values():
        joint, source = (hand.chain_joint_names.index(n) for n in (coupling.joint, coupling.source))
        assert torch.allclose(q_all[:, joint], coupling.scale * q_all[:, source] + coupling.offset, atol=1e-6)
    assert coupling_limit_problems(hand) == []


@pytest.mark.parametrize("name", BUILTIN_HANDS)
def test_mujoco_servos_reach_the_grasp_pose_with_couplings(name):
    hand = load_hand(name)
    model = hand_mjspec(hand).compile()
    assert model.nu == hand.dof
    assert model.neq == len(hand.spec.couplings)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("open").id)
    target = hand.pose("grasp").numpy()
    data.ctrl[:] = target
    for _ in range(1000):
        mujoco.mj_step(model, data)
    assert all(torch.isfinite(torch.from_numpy(data.qpos)))
    reached = np.array([data.joint(j).qpos[0] for j in hand.joint_names])
    tolerance = 0.1 * (hand.upper - hand.lower).numpy()
    assert (abs(reached - target) <= tolerance).all(), dict(zip(hand.joint_names, reached, strict=True))
    for coupling in hand.spec.couplings.values():
        joint, source = (data.joint(n).qpos[0] for n in (coupling.joint, coupling.source))
        assert joint == pytest.approx(coupling.scale * source + coupling.offset, abs=0.02)


@pytest.mark.parametrize("name", BUILTIN_HANDS)
def test_clouds_deterministic_per_seed_with_all_fingers(name):
    hand = load_hand(name)
    q = _random_states(hand, 4)
    a, b, c = (
        hand.point_cloud(q, 256, seed=1),
        hand.point_cloud(q, 256, seed=1),
        hand.point_cloud(q, 256, seed=2),
    )
    assert a.points.shape == (4, 256, 3) and a.labels.shape == (4, 256, 2) and a.joints.shape == (4, hand.dof)
    assert torch.equal(a.points, b.points)
    assert not torch.allclose(a.points, c.points)
    fingers = {hand.spec.links[link][0] for link in hand.link_names}
    assert set(a.labels[0, :, 0].tolist()) == fingers
    assert fingers >= {0, 1, 2}, "every end-effector has a palm and at least two opposing digits"


@pytest.mark.parametrize("name", BUILTIN_HANDS)
def test_cloud_moves_with_pose_and_keeps_n(name):
    hand = load_hand(name)
    cloud = hand.point_cloud(torch.stack([hand.pose("open"), hand.pose("grasp")]), 128)
    assert cloud.points.shape == (2, 128, 3)
    assert (cloud.points[0] - cloud.points[1]).norm(dim=-1).max() > 5e-3
    assert (cloud.points.abs() < 0.5).all(), "a hand fits in a metre-wide box around its wrist"


def _posed_from_fk(hand: HandModel, q: torch.Tensor, n_points: int) -> torch.Tensor:
    """Each surface point times its own link's pose: what a cloud is, computed the slow way."""
    samples = hand.surface_samples(n_points)
    poses = hand.forward_kinematics(q)[:, samples.link_index]  # (B, N, 4, 4)
    return (poses[..., :3, :3] @ samples.local_points[..., None]).squeeze(-1) + poses[..., :3, 3]


@pytest.mark.parametrize("name", BUILTIN_HANDS)
def test_cloud_is_each_point_posed_by_its_link(name):
    """Points on links no joint moves are posed once per batch: they must still be where FK puts them."""
    hand = load_hand(name)
    q = _random_states(hand, 8)
    assert torch.allclose(hand.point_cloud(q, 256).points, _posed_from_fk(hand, q, 256), atol=1e-6)
    assert hand.static_links & set(hand.link_names) == {hand.link_names[0]}, "the palm or gripper body"


def test_sampled_states_within_limits():
    hand = load_hand("umi")
    q = hand.sample_joints(1000, torch.Generator().manual_seed(0))
    assert (q >= hand.lower).all() and (q <= hand.upper).all()
    assert q.min() < hand.lower + 0.05 * (hand.upper - hand.lower)


def test_wrong_joint_shape_is_a_clear_error():
    hand = load_hand("umi")
    with pytest.raises(ValueError, match=r"expects joints of shape \(B, 1\)"):
        hand.point_cloud(torch.zeros(2, 3))


def test_user_urdf_with_meshes_works_like_builtin(user_allegro_spec):
    hand = HandModel.from_spec(user_allegro_spec)
    assert hand.dof == 16 and len(hand.link_names) == 21
    q = _random_states(hand)
    position_error, rotation_error = fk_error_vs_mujoco(hand, q)
    assert position_error < 1e-5 and rotation_error < 1e-5
    cloud = hand.point_cloud(q, 512, seed=0)
    assert cloud.points.shape == (16, 512, 3)
    assert set(cloud.labels[0, :, 0].tolist()) == {0, 1, 2, 3, 4}
    assert hand_mjspec(hand).compile().nu == 16


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    cpu, gpu = load_hand("umi"), load_hand("umi", device="cuda")
    q = _random_states(cpu)
    assert torch.allclose(cpu.point_cloud(q).points, gpu.point_cloud(q.cuda()).points.cpu(), atol=1e-5)
