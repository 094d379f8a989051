"""Checks that a hand model and its spec describe the same, sensible hand.

`python -m lerobot_opfa.hands.validate SPEC [--png OUT]` (also `lerobot-opfa hands check`): builds the
`HandModel` (which enforces the spec's structure), prints the link labels it took from the kinematic tree
(those the spec's `links` leaves out), compares its FK with MuJoCo's own kinematics, checks that couplings
keep coupled joints within their limits, says where the fingers point and the palm faces (warning when
that is not the documented frame, or a flexion joint bends away from the palm), and draws the open and
grasp poses coloured by finger (the labels from the tree included).
"""

from __future__ import annotations

import sys

import mujoco
import numpy as np
import torch

from lerobot_opfa.flags import OneLineParser, positive_int
from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.mujoco_model import hand_mjspec
from lerobot_opfa.hands.plot import plot_clouds
from lerobot_opfa.hands.registry import load_hand
from lerobot_opfa.hands.universal import FINGERS, UNIVERSAL_INDEX, UNIVERSAL_JOINTS

LIMIT_TOLERANCE = 1e-3
FRAME_TOLERANCE_DEG = 30.0
"""How far the fingers' or palm's measured direction may lie from the documented +z / +y."""
ORIGIN_TOLERANCE = 0.05
"""Metres the hand may lie from its frame's origin (the wrist flange), or reach behind it."""
FINGERS_POINT, PALM_FACES = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])


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


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-12)


def _degrees(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(_unit(a) @ _unit(b), -1.0, 1.0))))


def flexion_moves(hand: HandModel) -> dict[str, np.ndarray]:
    """Each flexion joint's own fingertip displacement (hand frame) as the joint moves from 10 % to 40 % of
    its range, the other joints in the open pose, signed so that it is the universal sense's flexion."""
    tips = {u: i for i, u in enumerate(sorted({hand.spec.links[link][0] for link in hand.fingertip_links}))}
    moves = {}
    for i, (joint, universal) in enumerate(zip(hand.joint_names, hand.universal_names, strict=True)):
        finger = UNIVERSAL_JOINTS[UNIVERSAL_INDEX[universal]].finger
        if not universal.endswith("_flex") or finger not in tips:
            continue
        q = hand.pose("open").repeat(2, 1)
        low, span = hand.lower[i], hand.upper[i] - hand.lower[i]
        q[:, i] = torch.tensor([low + 0.1 * span, low + 0.4 * span])
        positions = hand.fingertip_positions(q)[:, tips[finger]].double().cpu().numpy()
        moves[joint] = float(hand.universal_sign[i]) * (positions[1] - positions[0])
    return moves


def label_lines(hand: HandModel) -> list[str]:
    """The labels the kinematic tree gave the links the spec leaves out, one line per finger, so that a
    vendor's anonymous links can be checked before any cloud is trained on them."""
    if not hand.inferred_links:
        return ["labels: all from the spec's `links`"]
    segments: dict[int, dict[int, list[str]]] = {}
    for link, (u, v) in hand.inferred_links.items():
        segments.setdefault(u, {}).setdefault(v, []).append(link)
    lines = [f"labels from the kinematic tree, {len(hand.inferred_links)} links (`links` overrides any):"]
    for u, by_segment in sorted(segments.items()):
        listed = "; ".join(f"v{v} {', '.join(links)}" for v, links in sorted(by_segment.items()))
        lines.append(f"  {FINGERS[u]}: {listed}")
    return lines


def frame_report(hand: HandModel) -> tuple[list[str], list[str]]:
    """(lines saying where the hand lies in its frame, warnings where that is not the documented frame)."""
    cloud = hand.point_cloud(hand.pose("open")[None], 512)
    points, fingers = cloud.points[0].double().cpu().numpy(), cloud.labels[0, :, 0].cpu().numpy()
    tips = hand.fingertip_positions(hand.pose("open")[None])[0].double().cpu().numpy()
    palm = points[fingers == 0].mean(0) if (fingers == 0).any() else points.mean(0)
    pointing = _unit(tips.mean(0) - palm)
    origin = float(np.linalg.norm(points, axis=1).min())
    lines = [f"fingers point {np.round(pointing, 2).tolist()} (documented: +z)"]
    warnings = []
    if _degrees(pointing, FINGERS_POINT) > FRAME_TOLERANCE_DEG:
        warnings.append(
            f"the fingers point {_degrees(pointing, FINGERS_POINT):.0f} deg away from +z: give the spec a "
            "`base` (link, xyz, rpy) that puts the model in the documented hand frame"
        )
    moves = flexion_moves(hand) if hand.spec.kind == "hand" else {}  # a gripper's jaws close sideways
    if moves:
        flexion = sum(_unit(m) for m in moves.values())
        facing = _unit(flexion - (flexion @ pointing) * pointing)
        lines.append(f"palm faces {np.round(facing, 2).tolist()} (documented: +y)")
        if _degrees(facing, PALM_FACES) > FRAME_TOLERANCE_DEG:
            warnings.append(
                f"the palm faces {_degrees(facing, PALM_FACES):.0f} deg away from +y: rotate the model "
                "about z with the spec's `base.rpy`"
            )
        for joint, move in moves.items():
            if np.linalg.norm(move) > 1e-4 and _unit(move) @ facing < -0.3:
                warnings.append(
                    f"joint '{joint}' ({hand.spec.joints[joint]}) bends its finger away from the palm: if "
                    "the vendor's sense is the opposite of the universal table's, map it with `sign: -1`"
                )
    behind = float(-(points @ FINGERS_POINT).min())
    lines.append(
        f"nearest point of the hand {origin * 1000:.0f} mm from the origin, farthest behind it "
        f"{max(0.0, behind) * 1000:.0f} mm (documented: the origin at the wrist flange, the hand in front)"
    )
    if origin > ORIGIN_TOLERANCE or behind > ORIGIN_TOLERANCE:
        warnings.append(
            f"the hand lies {origin:.2f} m from the origin and reaches {behind:.2f} m behind it: set the "
            "spec's `base` (link, xyz) at the wrist"
        )
    return lines, warnings


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(description=__doc__.splitlines()[0])
    parser.add_argument("hand", help="built-in hand name or path to a spec.yaml")
    parser.add_argument("--png", help="draw the open and grasp poses to this PNG")
    parser.add_argument("--n-points", type=positive_int, default=2048)
    args = parser.parse_args(argv)

    hand = load_hand(args.hand)
    q = hand.sample_joints(64, torch.Generator().manual_seed(0))
    position_error, rotation_error = fk_error_vs_mujoco(hand, q)
    problems = coupling_limit_problems(hand)
    if position_error > 1e-5 or rotation_error > 1e-5:
        problems.append(f"FK disagrees with MuJoCo: {position_error:.2e} m, {rotation_error:.2e} rotation")
    print(f"{hand}\n  fingers: {hand.spec.fingers}")
    for line in label_lines(hand):
        print(f"  {line}")
    print(f"  FK vs MuJoCo: {position_error:.1e} m, {rotation_error:.1e}")
    mj = hand_mjspec(hand).compile()
    print(f"  MuJoCo: {mj.nbody} bodies, {mj.njnt} joints, {mj.nu} actuators, {mj.neq} couplings")
    lines, warnings = frame_report(hand)
    for line in lines:
        print(f"  {line}")
    if args.png:
        poses = torch.stack([hand.pose("open"), hand.pose("grasp")])
        cloud = hand.point_cloud(poses, args.n_points)
        clouds = {
            name: (cloud.points[i].cpu().numpy(), cloud.labels[i].cpu().numpy())
            for i, name in enumerate(("open", "grasp"))
        }
        print(f"  picture: {plot_clouds(clouds, args.png, title=hand.spec.description)}")
    for warning in warnings:
        print(f"  WARNING: {warning}")
    for problem in problems:
        print(f"  PROBLEM: {problem}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
