"""The body convention robots of different arms share: the pose of the hand's tool frame (its grasp centre
and approach axis, `envs.toolframe`, found from the hand's geometry) in the workspace frame, as a position
(m) and a continuous rotation, the 6D representation (the rotation matrix's first two columns; Zhou et al.,
"On the Continuity of Rotation Representations in Neural Networks", CVPR 2019: Euler angles and quaternions
have no continuous map from rotations, so a network regressing them jumps). The tool frame rather than the
hand's base: one grasp is one pose whatever the hand, where the bases of two hands grasping alike sit
centimetres and tens of degrees apart (docs/results.md, "Robots of different arms"). Conversions from the
conventions robots record: an arm's joints (`ArmBody`), the floating simulator wrist's Euler entries (its
tool frame already), and LeRobot's end-effector entries (a rotation vector, its gripper frame)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from lerobot_opfa.arms.ik import ArmChain, pose_error, solve_chunk
from lerobot_opfa.arms.spec import ArmSpec, ArmSpecError, load_arm
from lerobot_opfa.envs.scene import WRIST_JOINTS
from lerobot_opfa.envs.toolframe import tool_frame
from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.registry import load_hand

POSE_NAMES = ("x", "y", "z", "r11", "r21", "r31", "r12", "r22", "r32")
"""The wrist pose's entries: position, then the rotation matrix's first column, then its second."""
REACHED = (1e-3, 0.5 * torch.pi / 180)
"""m and rad: an IK answer farther than this from its pose is a pose out of reach (clamped, counted)."""
MOUNT_CLEARANCE = (0.03, 0.05, 0.02)
"""A mount puts its hand inside the arm when, the arm at home and the hand open, more than 2 % of the hand's
surface lies within 3 cm of the lines joining the arm's link frames, away from the flange (beyond 5 cm of
it, where the hand meets the arm). Measured: 0 % for umi, Inspire and LEAP on the UR5 and the Panda as
mounted; 10-56 % with the hand turned back into the arm or set 15 cm behind the flange."""


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


def matrix_rotation_vector(rotation: Tensor) -> Tensor:
    """(..., 3, 3) -> (..., 3) axis times angle, angle in [0, pi]: the inverse of `rotation_vector_matrix`.
    Near a half turn the antisymmetric part vanishes, so the axis is read from the symmetric part there."""
    r = rotation
    skew = torch.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1
    )
    sine = skew.norm(dim=-1) / 2
    cosine = (r.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2
    angle = torch.atan2(sine, cosine)
    outer = (r + r.transpose(-1, -2)) / 2 - cosine[..., None, None] * torch.eye(
        3, dtype=r.dtype, device=r.device
    )
    column = outer.norm(dim=-2).argmax(-1)[..., None, None].expand(*r.shape[:-2], 3, 1)
    axis = torch.nn.functional.normalize(outer.gather(-1, column).squeeze(-1), dim=-1)  # (1 - cos) k k^T
    axis = torch.where((axis * skew).sum(-1, keepdim=True) < 0, -axis, axis)
    near_half_turn = (angle > torch.pi - 1e-3).unsqueeze(-1)
    scale = torch.where(sine > 1e-12, angle / (2 * sine.clamp(min=1e-12)), torch.full_like(sine, 0.5))
    return torch.where(near_half_turn, axis * angle.unsqueeze(-1), skew * scale.unsqueeze(-1))


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
    tool_in_wrist: Tensor
    """(4, 4): the mounted hand's tool frame in its wrist frame (`wrist_in_tool` inverted)."""

    @classmethod
    def load(cls, arm: str, hand: HandModel) -> ArmBody:
        spec = load_arm(arm)
        chain = spec.chain()
        check_mount(spec, chain, hand)
        return cls(spec, chain, torch.linalg.inv(wrist_in_tool(hand)))

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.spec.joints

    @property
    def home(self) -> tuple[float, ...]:
        return self.spec.home

    @property
    def lower(self) -> Tensor:
        return self.chain.lower

    @property
    def upper(self) -> Tensor:
        return self.chain.upper

    @property
    def speed(self) -> Tensor:
        return self.chain.speed

    def pose(self, q: Tensor) -> Tensor:
        """(B, dof) arm joints -> (B, 9) tool poses."""
        return pose_vector(self.spec.wrist_pose(self.chain, q) @ self.tool_in_wrist).to(q.dtype)

    def joints(self, poses: Tensor, current: Tensor) -> tuple[Tensor, Tensor]:
        """(T, 9) tool poses -> (T, dof) joints within the limits, from the joints `current` the arm holds
        ((dof,) for all, or (T, dof) one per pose); and which poses were out of reach (T,), answered with the
        nearest pose the solver got to, never refused."""
        wrist = pose_matrix(poses.to(torch.float64)) @ torch.linalg.inv(self.tool_in_wrist)
        targets = self.spec.flange_target(wrist)
        q, _ = solve_chunk(self.chain, targets, current)
        error = pose_error(self.chain.flange_pose(q), targets)
        missed = (error[:, :3].norm(dim=-1) > REACHED[0]) | (error[:, 3:].norm(dim=-1) > REACHED[1])
        return q.to(poses.dtype), missed


def check_mount(spec: ArmSpec, chain: ArmChain, hand: HandModel) -> None:
    """Refuse a spec whose `mount` puts `hand` inside the arm (`MOUNT_CLEARANCE`; the links' meshes are not
    read: the lines through their frames stand for them)."""
    near, ball, share = MOUNT_CLEARANCE
    home = torch.tensor([spec.home], dtype=torch.float64)
    frames = chain.chain.forward_kinematics(home, end_only=False)
    names = list(frames)
    joints = torch.stack([(spec.base @ frames[name].get_matrix()[0])[:3, 3] for name in names])
    wrist = spec.wrist_pose(chain, home)[0]
    cloud = hand.point_cloud(hand.pose("open")[None].to(hand.dtype), 512).points[0].to(torch.float64)
    cloud = cloud @ wrist[:3, :3].T + wrist[:3, 3]
    start, line = joints[:-1], joints[1:] - joints[:-1]
    along = ((cloud[:, None] - start) * line).sum(-1) / (line * line).sum(-1).clamp(min=1e-12)
    closest = start + along.clamp(0.0, 1.0).unsqueeze(-1) * line  # (points, segments, 3)
    distance, segment = (cloud[:, None] - closest).norm(dim=-1).min(dim=1)
    flange = joints[-1]  # the chain's last frame
    inside = (distance < near) & ((closest[torch.arange(len(cloud)), segment] - flange).norm(dim=-1) > ball)
    fraction = float(inside.float().mean())
    if fraction > share:
        links = sorted({names[int(i) + 1] for i in segment[inside]}, key=names.index)
        raise ArmSpecError(
            spec.path, "mount",
            f"it puts the {hand.name} inside the arm ({100 * fraction:.0f} % of the hand's surface within "
            f"{100 * near:.0f} cm of {', '.join(links)}, the arm at home); `mount` is the hand's wrist frame "
            "in the flange frame: turn and move it so the hand points away from the flange",
        )  # fmt: skip


def nearest_turn(angle: Tensor, reference: Tensor) -> Tensor:
    """`angle` plus the whole turns that bring it nearest `reference`: an Euler angle read back from a pose
    continues the one the robot holds rather than jumping by 2 pi."""
    return reference + torch.remainder(angle - reference + torch.pi, 2 * torch.pi) - torch.pi


def wrist_in_tool(hand: HandModel) -> Tensor:
    """(4, 4): the hand's wrist (base) frame in its tool frame (grasp centre, approach axis +z), where the
    simulator's floating wrist carries it."""
    rotation, translation = tool_frame(hand).hand_in_tool()
    out = torch.eye(4, dtype=torch.float64)
    out[:3, :3], out[:3, 3] = torch.as_tensor(rotation), torch.as_tensor(translation)
    return out


@dataclass
class FloatingWrist:
    """The simulator's floating wrist as a body: its six entries (`WRIST_JOINTS`: x, y, z, yaw, pitch, roll)
    <-> the tool pose they drive (`floating_tool_pose`), both ways in closed form, so that a floating hand's
    demos share the convention of hands on arms. Pitch within +-pi/2, as the simulator's range keeps it."""

    name: str = "floating"
    joint_names: tuple[str, ...] = WRIST_JOINTS
    home: tuple[float, ...] = (0.0, 0.0, 0.3, 0.0, 0.0, 0.0)
    lower: Tensor = torch.full((6,), -torch.inf, dtype=torch.float64)
    upper: Tensor = torch.full((6,), torch.inf, dtype=torch.float64)
    speed: Tensor = torch.full((6,), torch.inf, dtype=torch.float64)

    def pose(self, q: Tensor) -> Tensor:
        return pose_vector(floating_tool_pose(q.to(torch.float64))).to(q.dtype)

    def joints(self, poses: Tensor, current: Tensor) -> tuple[Tensor, Tensor]:
        pose = pose_matrix(poses.to(torch.float64))
        half_turn = rotation_about(0, torch.full(poses.shape[:-1], torch.pi, dtype=torch.float64))
        r = pose[..., :3, :3] @ half_turn  # Rz(yaw) Ry(pitch) Rx(roll)
        yaw = torch.atan2(r[..., 1, 0], r[..., 0, 0])
        pitch = torch.asin((-r[..., 2, 0]).clamp(-1.0, 1.0))
        roll = torch.atan2(r[..., 2, 1], r[..., 2, 2])
        current = current.to(torch.float64)
        angles = [nearest_turn(a, current[..., 3 + i]) for i, a in enumerate((yaw, pitch, roll))]
        q = torch.cat([pose[..., :3, 3], torch.stack(angles, dim=-1)], dim=-1)
        return q.to(poses.dtype), torch.zeros(poses.shape[:-1], dtype=torch.bool)


@dataclass
class EndEffectorPose:
    """LeRobot's end-effector entries as a body (`ee.x, ee.y, ee.z` in metres, `ee.wx, ee.wy, ee.wz` a
    rotation vector, as its kinematic processor steps for the SO-100/101 write them) <-> the wrist pose, with
    no arm model: the robot's own IK turns the pose into its joints."""

    name: str = "end_effector"
    joint_names: tuple[str, ...] = ("ee.x", "ee.y", "ee.z", "ee.wx", "ee.wy", "ee.wz")
    home: tuple[float, ...] = (0.0, 0.0, 0.3, 0.0, 0.0, 0.0)
    lower: Tensor = torch.full((6,), -torch.inf, dtype=torch.float64)
    upper: Tensor = torch.full((6,), torch.inf, dtype=torch.float64)
    speed: Tensor = torch.full((6,), torch.inf, dtype=torch.float64)

    def pose(self, q: Tensor) -> Tensor:
        q64 = q.to(torch.float64)
        rotation = rotation_vector_matrix(q64[..., 3:])
        return torch.cat([q64[..., :3], rotation[..., :, 0], rotation[..., :, 1]], dim=-1).to(q.dtype)

    def joints(self, poses: Tensor, current: Tensor) -> tuple[Tensor, Tensor]:
        pose = pose_matrix(poses.to(torch.float64))
        q = torch.cat([pose[..., :3, 3], matrix_rotation_vector(pose[..., :3, :3])], dim=-1)
        return q.to(poses.dtype), torch.zeros(poses.shape[:-1], dtype=torch.bool)


POSE_BODIES = (FloatingWrist.name, EndEffectorPose.name)
"""The bodies a joint map's `arm` may name that are poses already, not an arm's joints."""


def load_body(arm: str, hand: str) -> ArmBody | FloatingWrist | EndEffectorPose:
    """The body a joint map's `arm` names for its slot's `hand` (what `load_hand` takes): a pose body
    (`POSE_BODIES`), else an arm (`arms.spec.load_arm`)."""
    if arm == FloatingWrist.name:
        return FloatingWrist()
    return EndEffectorPose() if arm == EndEffectorPose.name else ArmBody.load(arm, load_hand(hand))
