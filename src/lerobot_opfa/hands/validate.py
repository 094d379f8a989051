"""Checks that a hand model and its spec describe the same, sensible hand.

`python -m lerobot_opfa.hands.validate SPEC [--png OUT]` (also `lerobot-opfa hands check`): builds the
`HandModel` (which enforces the spec's structure), compares its FK with MuJoCo's own kinematics, checks
that couplings keep coupled joints within their limits, and draws the open and grasp poses.
"""

from __future__ import annotations

import argparse
import sys

import mujoco
import numpy as np
import torch

from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.mujoco_model import hand_mjspec
from lerobot_opfa.hands.plot import plot_clouds
from lerobot_opfa.hands.registry import load_hand

LIMIT_TOLERANCE = 1e-3


def mujoco_link_poses(hand: HandModel, q: torch.Tensor, model: mujoco.MjModel | None = None) -> np.ndarray:
    """(B, dof) -> (B, L, 4, 4) poses of `hand.link_names` computed by MuJoCo's `mj_kinematics`."""
    model = model or hand_mjspec(hand).compile()
    data = mujoco.MjData(model)
    q_all = hand.expand(q.to(hand.device, hand.dtype)).double().cpu().numpy()
    qpos_index = [model.jnt_qposadr[model.joint(name).id] for name in hand.chain_joint_names]
    bodies = [model.body(link).id for link in hand.link_names]
    out = np.tile(np.eye(4), (len(q_all), len(bodies), 1, 1))
    for b, values in enumerate(q_all):
        data.qpos[qpos_index] = values
        mujoco.mj_kinematics(model, data)
        out[b, :, :3, :3] = data.xmat[bodies].reshape(-1, 3, 3)
        out[b, :, :3, 3] = data.xpos[bodies]
    return out


def fk_error_vs_mujoco(hand: HandModel, q: torch.Tensor) -> tuple[float, float]:
    """Largest link position error (m) and rotation-matrix entry error between our FK and MuJoCo's."""
    ours = hand.forward_kinematics(q).double().cpu().numpy()
    theirs = mujoco_link_poses(hand, q)
    return float(np.abs(ours[..., :3, 3] - theirs[..., :3, 3]).max()), float(
        np.abs(ours[..., :3, :3] - theirs[..., :3, :3]).max()
    )


def coupling_limit_problems(hand: HandModel) -> list[str]:
    """Coupled joints that the actuated joints' full range would drive past their own limits."""
    matrix, offset = hand._coupling_matrix, hand._coupling_offset
    low = offset + (matrix.clamp(min=0) * hand._lower + matrix.clamp(max=0) * hand._upper).sum(1)
    high = offset + (matrix.clamp(min=0) * hand._upper + matrix.clamp(max=0) * hand._lower).sum(1)
    problems = []
    for joint in hand.spec.couplings:
        j = hand.chain_joint_names.index(joint)
        if low[j] < hand._lower_all[j] - LIMIT_TOLERANCE or high[j] > hand._upper_all[j] + LIMIT_TOLERANCE:
            problems.append(
                f"coupled joint '{joint}' reaches [{low[j]:.3f}, {high[j]:.3f}] but its limits are "
                f"[{hand._lower_all[j]:.3f}, {hand._upper_all[j]:.3f}]"
            )
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("hand", help="built-in hand name or path to a spec.yaml")
    parser.add_argument("--png", help="draw the open and grasp poses to this PNG")
    parser.add_argument("--n-points", type=int, default=2048)
    args = parser.parse_args(argv)

    hand = load_hand(args.hand)
    q = hand.sample_joints(64, torch.Generator().manual_seed(0))
    position_error, rotation_error = fk_error_vs_mujoco(hand, q)
    problems = coupling_limit_problems(hand)
    if position_error > 1e-5 or rotation_error > 1e-5:
        problems.append(f"FK disagrees with MuJoCo: {position_error:.2e} m, {rotation_error:.2e} rotation")
    print(f"{hand}\n  fingers: {hand.spec.fingers}")
    print(f"  FK vs MuJoCo: {position_error:.1e} m, {rotation_error:.1e}")
    mj = hand_mjspec(hand).compile()
    print(f"  MuJoCo: {mj.nbody} bodies, {mj.njnt} joints, {mj.nu} actuators, {mj.neq} couplings")
    if args.png:
        poses = torch.stack([hand.pose("open"), hand.pose("grasp")])
        cloud = hand.point_cloud(poses, args.n_points)
        clouds = {
            name: (cloud.points[i].cpu().numpy(), cloud.labels[i].cpu().numpy())
            for i, name in enumerate(("open", "grasp"))
        }
        print(f"  picture: {plot_clouds(clouds, args.png, title=hand.spec.description)}")
    for problem in problems:
        print(f"  PROBLEM: {problem}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
