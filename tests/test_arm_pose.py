"""The body convention: a wrist pose as position + 6D rotation, from an arm's joints (FK) and back (IK
seeded at the joints the arm holds), from the floating simulator wrist's Euler entries (as MuJoCo poses the
scene's tool frame) and from LeRobot's end-effector rotation vector."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

from lerobot_opfa.arms.pose import (
    ArmBody,
    EndEffectorPose,
    FloatingWrist,
    floating_tool_pose,
    load_body,
    matrix_rotation_vector,
    pose_matrix,
    pose_vector,
    rotation_vector_matrix,
    wrist_in_tool,
)
from lerobot_opfa.envs.env import OpfaSimEnv
from lerobot_opfa.envs.scene import WRIST_RANGE
from lerobot_opfa.hands.registry import load_hand


def random_rotations(n: int, seed: int = 0) -> torch.Tensor:
    q = torch.nn.functional.normalize(
        torch.randn(n, 4, generator=torch.Generator().manual_seed(seed)), dim=-1
    )
    out = np.zeros((n, 9))
    for row, quat in zip(out, q.double().numpy(), strict=True):
        mujoco.mju_quat2Mat(row, quat)
    return torch.from_numpy(out).reshape(n, 3, 3)


def test_the_6d_rotation_round_trips_and_a_perturbed_one_still_names_a_rotation():
    pose = torch.eye(4, dtype=torch.float64).repeat(32, 1, 1)
    pose[:, :3, :3], pose[:, :3, 3] = random_rotations(32), torch.randn(32, 3, dtype=torch.float64)
    assert torch.allclose(pose_matrix(pose_vector(pose)), pose, atol=1e-12)
    noisy = pose_matrix(pose_vector(pose) + 0.05 * torch.randn(32, 9, dtype=torch.float64))
    rotation = noisy[:, :3, :3]
    assert torch.allclose(rotation @ rotation.transpose(1, 2), torch.eye(3, dtype=torch.float64), atol=1e-12)
    assert torch.allclose(torch.linalg.det(rotation), torch.ones(32, dtype=torch.float64))


def test_the_floating_wrists_entries_give_the_tool_pose_mujoco_gives_the_scene():
    env = OpfaSimEnv("lift", "umi", obs_type="state")
    arm = env.scene.arms[None]
    tool = env.model.body("tool").id
    generator = np.random.default_rng(0)
    for wrist in generator.uniform(WRIST_RANGE[:, 0], WRIST_RANGE[:, 1], (16, 6)):
        env.data.qpos[arm.wrist_qpos] = wrist
        mujoco.mj_kinematics(env.model, env.data)
        ours = floating_tool_pose(torch.from_numpy(wrist)).numpy()
        assert np.abs(ours[:3, 3] - env.data.xpos[tool]).max() < 1e-9
        assert np.abs(ours[:3, :3] - env.data.xmat[tool].reshape(3, 3)).max() < 1e-9
    env.close()


def test_lerobots_rotation_vector_is_read_as_mujoco_reads_an_axis_angle():
    vectors = torch.randn(16, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    for vector, ours in zip(vectors, rotation_vector_matrix(vectors), strict=True):
        angle = float(vector.norm())
        quat, matrix = np.zeros(4), np.zeros(9)
        mujoco.mju_axisAngle2Quat(quat, (vector / angle).numpy(), angle)
        mujoco.mju_quat2Mat(matrix, quat)
        assert np.abs(ours.numpy() - matrix.reshape(3, 3)).max() < 1e-12
    assert torch.allclose(rotation_vector_matrix(torch.zeros(1, 3)), torch.eye(3)[None])


def test_a_rotation_vector_comes_back_from_its_matrix_near_no_turn_and_a_half_turn():
    axes = torch.nn.functional.normalize(
        torch.randn(64, 3, generator=torch.Generator().manual_seed(2)), dim=-1
    )
    angles = torch.cat(
        [torch.tensor([0.0, 1e-9, 1e-4, math.pi - 1e-4, math.pi - 1e-9]), torch.rand(59) * math.pi]
    )
    vectors = (axes.double() * angles.double()[:, None])[:-1]
    back = matrix_rotation_vector(rotation_vector_matrix(vectors))
    assert torch.allclose(rotation_vector_matrix(back), rotation_vector_matrix(vectors), atol=1e-9)
    assert torch.allclose(back[:3], vectors[:3], atol=1e-9) and torch.allclose(
        back[5:], vectors[5:], atol=1e-9
    )


@pytest.mark.parametrize("name", ["floating", "end_effector"])
def test_a_pose_body_gives_back_the_entries_its_pose_came_from(name):
    """The simulator's floating wrist carrying an Inspire hand (within its range) and LeRobot's end-effector
    entries come back from the wrist pose in closed form; the floating wrist's yaw continues the one it
    holds, not 2 pi off."""
    body = load_body(name, "inspire")
    generator = np.random.default_rng(3)
    entries = torch.from_numpy(generator.uniform(WRIST_RANGE[:, 0], WRIST_RANGE[:, 1], (64, 6)))
    if isinstance(body, EndEffectorPose):
        entries[:, 3:] = torch.from_numpy(generator.normal(0, 1, (64, 3))).clamp(-1.5, 1.5)
    current = torch.tensor(body.home, dtype=torch.float64)
    back, missed = body.joints(body.pose(entries), current)
    assert not missed.any() and torch.allclose(back, entries, atol=1e-9)
    if isinstance(body, FloatingWrist):
        turned = entries.clone()
        turned[:, 3] += 2 * math.pi
        near_turn = current.clone()
        near_turn[3] = 2 * math.pi
        assert torch.allclose(body.joints(body.pose(turned), near_turn)[0], turned, atol=1e-9)


@pytest.mark.parametrize("arm", ["ur5", "panda"])
def test_recorded_arm_joints_come_back_through_the_tool_pose_within_a_millimetre_and_half_a_degree(arm):
    body = ArmBody.load(arm, load_hand("inspire"))
    home = torch.tensor(body.spec.home, dtype=torch.float64)
    t = torch.linspace(0, 2 * math.pi, 60, dtype=torch.float64)[:, None]
    phases = torch.arange(len(home), dtype=torch.float64)
    recorded = home + 0.25 * torch.sin(t + phases)  # a smooth recorded trajectory about home, 60 frames
    poses = body.pose(recorded)
    assert poses.shape == (60, 9)
    for previous, frame in zip(recorded[:-1], range(1, 60), strict=True):
        q, missed = body.joints(poses[frame : frame + 1], previous)
        assert not missed.any()
        error = pose_matrix(body.pose(q))[0].inverse() @ pose_matrix(poses[frame])
        assert error[:3, 3].norm() < 1e-3
        assert math.degrees(math.acos(min(1.0, (error[:3, :3].trace().item() - 1) / 2))) < 0.5
    far = poses[:1].clone()
    far[0, 0] += 2.0  # 2 m beyond the table: out of any arm's reach
    q, missed = body.joints(far, home)
    assert missed.all() and q.isfinite().all()
    assert ((q >= body.chain.lower) & (q <= body.chain.upper)).all()


def test_the_tool_frame_sits_on_the_hands_wrist_as_in_the_scene():
    """The transform an arm's pose takes from the hand's wrist (its base body, what the arm's flange
    carries) to its tool frame is the one between the scene's hand and tool bodies."""
    env = OpfaSimEnv("lift", "inspire", obs_type="state")
    arm = env.scene.arms[None]
    tool_in_wrist = torch.linalg.inv(wrist_in_tool(env.hand_models[None])).numpy()
    root = next(i for i in range(env.model.nbody) if env.model.body(i).name.startswith("hand/"))
    tool = env.model.body("tool").id

    def pose(body: int) -> np.ndarray:
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = env.data.xmat[body].reshape(3, 3), env.data.xpos[body]
        return out

    for wrist in np.random.default_rng(4).uniform(WRIST_RANGE[:, 0], WRIST_RANGE[:, 1], (8, 6)):
        env.data.qpos[arm.wrist_qpos] = wrist
        mujoco.mj_kinematics(env.model, env.data)
        assert np.abs(pose(root) @ tool_in_wrist - pose(tool)).max() < 1e-9
    env.close()
