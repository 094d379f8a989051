"""An arm's inverse kinematics: the joints that put its flange at a pose, within the joint limits, by
batched damped least squares on pytorch-kinematics' Jacobian, seeded at the joints the arm holds.

Why not pytorch-kinematics' own `PseudoInverseIK`: on one CPU thread it took 60-140 ms for a 16-pose chunk
and left 5 % of poses 35-170 mm off (its default step overshoots near singular poses); a damped step from
the current joints converges in a few iterations (`benchmarks/results/ik.json`).
"""

from __future__ import annotations

import contextlib
import io
import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import pytorch_kinematics as pk
import torch
from torch import Tensor

DAMPING = 1e-3
"""The damping (squared, in m^2 and rad^2) that keeps a step finite at a singular pose."""
MAX_STEP = 0.2
"""rad (or m): the most one iteration moves a joint, so that a pose out of reach never sends a jump."""


@dataclass
class ArmChain:
    """An arm's kinematic chain from its base link to its flange, in float64, with its joint limits."""

    chain: pk.SerialChain
    lower: Tensor
    upper: Tensor
    speed: Tensor
    """(dof,) each joint's velocity limit (rad/s, m/s) as the model gives it; inf where it gives none."""

    @classmethod
    def from_model(cls, path: Path | str, flange: str) -> ArmChain:
        """The chain of the URDF or MJCF `path` up to the link (MJCF: body) `flange`; a missing file or link
        is one line."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"{path}: arm model file not found")
        if path.suffix in (".xml", ".mjcf"):
            chain = _mjcf_chain(path, flange)
        else:
            # pytorch-kinematics' URDF reader writes a line to stderr for each vendor attribute it does not
            # know (the Panda's: 28 lines of joint dynamics); the chain is what is read here, not those.
            with contextlib.redirect_stderr(io.StringIO()):
                links = pk.build_chain_from_urdf(path.read_bytes()).get_link_names()
                if flange not in links:
                    raise ValueError(
                        f"{path}: flange link '{flange}' is not a link of the model ({', '.join(links)})"
                    )
                chain = pk.build_serial_chain_from_urdf(path.read_bytes(), flange)
        chain = chain.to(dtype=torch.float64)
        lower, upper = (torch.as_tensor(limit, dtype=torch.float64) for limit in chain.get_joint_limits())
        speed = torch.as_tensor(chain.get_joint_velocity_limits()[1], dtype=torch.float64)
        return cls(chain, lower, upper, torch.where(speed > 0, speed, torch.inf))

    @property
    def joint_names(self) -> list[str]:
        return self.chain.get_joint_parameter_names()

    def flange_pose(self, q: Tensor) -> Tensor:
        """(B, 4, 4) flange poses in the base frame of joints `q` (B, dof)."""
        return self.chain.forward_kinematics(q).get_matrix()


MJCF_JOINTS = {mujoco.mjtJoint.mjJNT_HINGE: "revolute", mujoco.mjtJoint.mjJNT_SLIDE: "prismatic"}


def _mjcf_chain(path: Path, flange: str) -> pk.SerialChain:
    """The serial chain from the world to the body `flange` of an MJCF, as MuJoCo compiles it (meshes found
    beside the file; pytorch-kinematics' own MJCF reader reads a string, so not those, and does not know
    MuJoCo 3's joint type values)."""
    model = mujoco.MjModel.from_xml_path(str(path))
    bodies = [model.body(i).name for i in range(1, model.nbody)]
    if flange not in bodies:
        raise ValueError(f"{path}: flange body '{flange}' is not a body of the model ({', '.join(bodies)})")
    route, body = [], model.body(flange).id
    while body != 0:
        route.append(body)
        body = int(model.body_parentid[body])
    parent = root = pk.frame.Frame("world", link=pk.frame.Link("world"), joint=pk.frame.Joint())
    for body in map(model.body, reversed(route)):
        if body.jntnum[0] > 1:
            raise ValueError(
                f"{path}: body '{body.name}' has {body.jntnum[0]} joints; an arm's bodies have one"
            )
        joint = pk.frame.Joint(f"{body.name}_fixed")
        if body.jntnum[0] == 1:
            mj = model.joint(body.jntadr[0])
            kind = MJCF_JOINTS.get(mujoco.mjtJoint(int(mj.type[0])))
            if kind is None:
                raise ValueError(f"{path}: joint '{mj.name}' is neither a hinge nor a slide")
            limits = (mj.range[0], mj.range[1]) if model.jnt_limited[mj.id] else (-math.inf, math.inf)
            offset = pk.transforms.Transform3d(pos=mj.pos)
            joint = pk.frame.Joint(mj.name, offset=offset, axis=mj.axis, joint_type=kind, limits=limits)
        link = pk.frame.Link(body.name, offset=pk.transforms.Transform3d(rot=body.quat, pos=body.pos))
        child = pk.frame.Frame(body.name, link=link, joint=joint)
        parent.children = [child]
        parent = child
    return pk.SerialChain(pk.Chain(root), flange)


def pose_error(current: Tensor, target: Tensor) -> Tensor:
    """(B, 6): the translation (m) and rotation vector (rad) that take poses `current` (B, 4, 4) to
    `target`, in the base frame."""
    rotation = target[:, :3, :3] @ current[:, :3, :3].transpose(1, 2)
    cos = ((rotation.diagonal(dim1=1, dim2=2).sum(-1) - 1) / 2).clamp(-1.0, 1.0)
    angle = torch.acos(cos)
    axis = torch.stack(
        [rotation[:, 2, 1] - rotation[:, 1, 2], rotation[:, 0, 2] - rotation[:, 2, 0],
         rotation[:, 1, 0] - rotation[:, 0, 1]], dim=-1,
    )  # fmt: skip
    scale = torch.where(
        angle < 1e-6, torch.full_like(angle, 0.5), angle / (2 * torch.sin(angle).clamp(min=1e-9))
    )
    return torch.cat([target[:, :3, 3] - current[:, :3, 3], axis * scale.unsqueeze(-1)], dim=-1)


def solve(arm: ArmChain, targets: Tensor, seed: Tensor, iterations: int = 8) -> tuple[Tensor, Tensor]:
    """Joints (B, dof) that put the flange at `targets` (B, 4, 4), from `seed` (B, dof), each within its
    limits; and the pose error left (B, 6), which is large for a pose out of reach (clamped to the nearest
    pose the limits allow, never a failure)."""
    q = seed.to(torch.float64).clone()
    eye = torch.eye(6, dtype=torch.float64)
    for _ in range(iterations):
        jacobian, pose = arm.chain.jacobian(q, ret_eef_pose=True)
        error = pose_error(pose, targets)
        damped = jacobian @ jacobian.transpose(1, 2) + DAMPING * eye
        step = (jacobian.transpose(1, 2) @ torch.linalg.solve(damped, error.unsqueeze(-1))).squeeze(-1)
        q = torch.minimum(torch.maximum(q + step.clamp(-MAX_STEP, MAX_STEP), arm.lower), arm.upper)
    return q, pose_error(arm.flange_pose(q), targets)


def within_speed(q: Tensor, held: Tensor, step: Tensor) -> tuple[Tensor, Tensor]:
    """Joints (B, T, dof) for T successive actions from the joints `held` (B, dof) now, each moved at most
    `step` (dof,) from the one before: an IK answer that could not converge, or a pose far from the last,
    never sends a jump the arm cannot make in one action. Also which actions were held back (B, T)."""
    out, limited, previous = [], [], held
    for t in range(q.shape[1]):
        bounded = torch.minimum(torch.maximum(q[:, t], previous - step), previous + step)
        limited.append((bounded != q[:, t]).any(dim=-1))
        out.append(bounded)
        previous = bounded
    return torch.stack(out, dim=1), torch.stack(limited, dim=1)


def solve_chunk(
    arm: ArmChain, targets: Tensor, current: Tensor, iterations: int = 8
) -> tuple[Tensor, Tensor]:
    """Joints (T, dof) for a chunk of flange poses `targets` (T, 4, 4), every pose seeded at the joints the
    arm holds now (`current`: (dof,), or (T, dof), one row per pose, for a batch of robots' chunks) and all
    solved in one batch: a chunk's poses lie close together, and one batch costs about what one pose does
    (`solve`)."""
    return solve(arm, targets, current.to(torch.float64).expand(len(targets), -1), iterations)
