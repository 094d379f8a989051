"""The body convention robots of different arms share: the hand's wrist pose in the workspace frame, as a
position (m) and a continuous rotation, the 6D representation (the rotation matrix's first two columns;
Zhou et al., "On the Continuity of Rotation Representations in Neural Networks", CVPR 2019: Euler angles and
quaternions have no continuous map from rotations, so a network regressing them jumps). Conversions from the
conventions robots record: an arm's joints (`ArmBody`), the floating simulator wrist's Euler entries, and
LeRobot's end-effector entries (a rotation vector)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from lerobot_opfa.arms.ik import ArmChain, pose_error, solve_chunk
from lerobot_opfa.arms.spec import ArmSpec, load_arm

POSE_NAMES = ("x", "y", "z", "r11", "r21", "r31", "r12", "r22", "r32")
"""The wrist pose's entries: position, then the rotation matrix's first column, then its second."""
REACHED = (1e-3, 0.5 * torch.pi / 180)
"""m and rad: an IK answer farther than this from its pose is a pose out of reach (clamped, counted)."""


def pose_vector(pose: Tensor) -> Tensor:
    """(..., 4, 4) -> (..., 9): position, then the rotation's first two columns."""
    return torch.cat([pose[..., :3, 3], pose[..., :3, 0], pose[..., :3, 1]], dim=-1)


def pose_matrix(vector: Tensor) -> Tensor:
    """(..., 9) -> (..., 4, 4), the two columns made orthonormal (Gram-Schmidt) so a predicted vector that is
    slightly off still names a rotation."""
    first = torch.nn.functional.normalize(vector[..., 3:6], dim=-1)
    second = vector[..., 6:9] - (first * vector[..., 6:9]).sum(-1, keepdim=True) * first
    second = torch.nn.functional.normalize(second, dim=-1)
    out = torch.zeros(*vector.shape[:-1], 4, 4, dtype=vector.dtype, device=vector.device)
    out[..., :3, 0], out[..., :3, 1], out[..., :3, 2] = first, second, torch.cross(first, second, dim=-1)
    out[..., :3, 3], out[..., 3, 3] = vector[..., :3], 1.0
    return out


def rotation_about(axis: int, angle: Tensor) -> Tensor:
    """(..., 3, 3) rotations by `angle` (...) about the x (0), y (1) or z (2) axis."""
    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(angle), torch.zeros_like(angle)
    rows = {
        0: [[one, zero, zero], [zero, c, -s], [zero, s, c]],
        1: [[c, zero, s], [zero, one, zero], [-s, zero, c]],
        2: [[c, -s, zero], [s, c, zero], [zero, zero, one]],
    }[axis]
    return torch.stack([torch.stack(row, dim=-1) for row in rows], dim=-2)


def floating_tool_pose(wrist: Tensor) -> Tensor:
    """(..., 6) -> (..., 4, 4): the simulator's floating wrist entries (`envs.scene.WRIST_JOINTS`: x, y, z,
    then yaw, pitch, roll, R = Rz Ry Rx) -> its tool frame in the workspace (a half turn about x after the
    carriage: the approach axis +z points down at zero angles)."""
    yaw, pitch, roll = wrist[..., 3], wrist[..., 4], wrist[..., 5]
    half_turn = rotation_about(0, torch.full_like(yaw, torch.pi))
    out = torch.zeros(*wrist.shape[:-1], 4, 4, dtype=wrist.dtype, device=wrist.device)
    out[..., :3, :3] = rotation_about(2, yaw) @ rotation_about(1, pitch) @ rotation_about(0, roll) @ half_turn
    out[..., :3, 3], out[..., 3, 3] = wrist[..., :3], 1.0
    return out


def rotation_vector_matrix(rotation: Tensor) -> Tensor:
    """(..., 3) axis times angle (LeRobot's `ee.wx, ee.wy, ee.wz`) -> (..., 3, 3), by Rodrigues' formula."""
    angle = rotation.norm(dim=-1, keepdim=True)
    axis = rotation / angle.clamp(min=1e-12)
    x, y, z = axis.unbind(-1)
    zero = torch.zeros_like(x)
    cross = torch.stack(
        [torch.stack(row, dim=-1) for row in ([zero, -z, y], [z, zero, -x], [-y, x, zero])], dim=-2
    )
    angle = angle.unsqueeze(-1)
    eye = torch.eye(3, dtype=rotation.dtype, device=rotation.device)
    return eye + torch.sin(angle) * cross + (1 - torch.cos(angle)) * cross @ cross


@dataclass
class ArmBody:
    """An arm's joints <-> its hand's wrist pose in the workspace (`pose_vector`): FK on the way in, IK
    seeded at the joints the arm holds on the way out."""

    spec: ArmSpec
    chain: ArmChain

    @classmethod
    def load(cls, arm: str) -> ArmBody:
        spec = load_arm(arm)
        return cls(spec, spec.chain())

    def wrist_pose(self, q: Tensor) -> Tensor:
        """(B, dof) arm joints -> (B, 9) wrist poses."""
        return pose_vector(self.spec.wrist_pose(self.chain, q)).to(q.dtype)

    def joints(self, poses: Tensor, current: Tensor) -> tuple[Tensor, Tensor]:
        """(T, 9) wrist poses of a chunk -> (T, dof) joints within the limits, from the joints `current`
        (dof,) the arm holds; and which poses were out of reach (T,), answered with the nearest pose the
        solver got to, never refused."""
        targets = self.spec.flange_target(pose_matrix(poses.to(torch.float64)))
        q, _ = solve_chunk(self.chain, targets, current)
        error = pose_error(self.chain.flange_pose(q), targets)
        missed = (error[:, :3].norm(dim=-1) > REACHED[0]) | (error[:, 3:].norm(dim=-1) > REACHED[1])
        return q.to(poses.dtype), missed
