"""Checks that a hand model and its spec describe the same, sensible hand.

`python -m lerobot_opfa.hands.validate SPEC [--png OUT] [--suggest]` (also `lerobot-opfa hands check`): builds
the `HandModel` (which enforces the spec's structure), prints the link labels it took from the kinematic
tree (those the spec's `links` leaves out), compares its FK with MuJoCo's own kinematics, checks that
couplings keep coupled joints within their limits, says where the fingers point and the palm faces and
which hand it is, measured without the spec's signs (`hands.frame`; warning when that is not the documented
frame), refuses flexion signs and a side that contradict the model, and draws the open and grasp poses
coloured by finger (the labels from the tree included). `--suggest` prints the base, side and signs
measured, as spec YAML."""

from __future__ import annotations

import sys

import mujoco
import numpy as np
import torch

from lerobot_opfa.flags import OneLineParser, positive_int
from lerobot_opfa.hands import frame
from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.mujoco_model import hand_mjspec
from lerobot_opfa.hands.plot import plot_clouds
from lerobot_opfa.hands.registry import load_hand
from lerobot_opfa.hands.universal import FINGERS

LIMIT_TOLERANCE = 1e-3
FRAME_TOLERANCE_DEG = 30.0
"""How far the fingers' or palm's measured direction may lie from the documented +z / +y."""
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


def _degrees(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


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


def _joint_list(joints: list[str]) -> str:
    return ", ".join(f"'{joint}'" for joint in joints)


def frame_report(hand: HandModel) -> tuple[list[str], list[str], list[str]]:
    """(lines saying where the hand lies, which hand it is and which way it flexes; warnings where that is
    not the documented frame; problems where the spec's signs or side contradict the model)."""
    measured = frame.measure(hand)
    point, palm = measured.fingers_point, measured.palm_faces
    named = ", ".join(FINGERS[u] for u in measured.pointing_fingers)
    lines = [f"fingers point {np.round(point, 2).tolist()} (documented: +z), measured along the {named}"]
    warnings, problems, off = [], [], []
    if _degrees(point, FINGERS_POINT) > FRAME_TOLERANCE_DEG:
        off.append(f"the fingers point {_degrees(point, FINGERS_POINT):.0f} deg away from +z")
    if palm is not None:
        lines.append(f"palm faces {np.round(palm, 2).tolist()} (documented: +y): where the fingers curl")
        if _degrees(palm, PALM_FACES) > FRAME_TOLERANCE_DEG:
            off.append(f"the palm faces {_degrees(palm, PALM_FACES):.0f} deg away from +y")
    elif hand.spec.kind == "hand":
        warnings.append(
            "the flexion joints' ranges reach as far both ways from 0, so the palm's side and the signs of "
            "the fingers' flexions are not checked: look at the `--png` picture"
        )
    lines.append(
        f"nearest point of the hand {measured.nearest * 1000:.0f} mm from the origin, farthest behind it "
        f"{measured.behind * 1000:.0f} mm (documented: the origin at the wrist flange, the hand in front)"
    )
    if frame.origin_is_off(measured):
        off.append(
            f"the hand lies {measured.nearest:.2f} m from the origin, {measured.behind:.2f} m behind it"
        )
    if off:
        base = frame.suggested_base(hand, measured)
        fix = "a `base` (link, xyz, rpy)" if base is None else f"`{frame.base_yaml(base)}`"
        warnings.append(f"{'; '.join(off)}: put the model in the documented hand frame with {fix}")

    if measured.side is not None:
        where = f"the {measured.side_told_by} on {'-x' if measured.side == 'right' else '+x'}"
        lines.append(f"a {measured.side} hand: {where} (spec: {hand.spec.side})")
        if measured.side != hand.spec.side:
            problems.append(
                f"the model is a {measured.side} hand ({where}, the palm on +y, the fingers on "
                f"+z), the spec a {hand.spec.side} one: use the vendor's {hand.spec.side}-hand model, or "
                f"declare `side: {measured.side}`"
            )
    if frame.fingers_out_of_order(measured):
        order = ", ".join(FINGERS[u] for u in measured.across)
        problems.append(
            f"the fingertips lie across the palm as {order} from the thumb's side, not in the order index, "
            "middle, ring, little: the joints in `joints` give some fingers another finger's universal names"
        )
    if measured.flexion:
        cosines: dict[int, list[str]] = {}
        for joint, cosine in measured.flexion.items():
            cosines.setdefault(frame.finger_of(hand.spec.joints[joint]), []).append(f"{cosine:+.2f}")
        listed = "; ".join(f"{FINGERS[u]} {' '.join(c)}" for u, c in sorted(cosines.items()))
        lines.append(f"flexion towards the palm (the thumb's: the fingertips), cosine per joint: {listed}")
    flip = frame.signs_to_flip(measured)
    if flip:
        add = [j for j in flip if j not in hand.spec.signs]
        drop = [j for j in flip if j in hand.spec.signs]
        fixes = ([f"add `sign: -1` to joint(s) {_joint_list(add)}"] if add else []) + (
            [f"remove `sign: -1` from joint(s) {_joint_list(drop)}"] if drop else []
        )
        problems.append(
            f"{len(flip)} flexion joint(s) curl their finger away from the palm (a thumb: from the "
            f"fingertips), against the universal sense: {' and '.join(fixes)} in `joints` (`--suggest`)"
        )
    unclear = frame.unclear_flexions(measured)
    if unclear:
        warnings.append(
            f"joint(s) {_joint_list(unclear)} move their fingertip neither towards nor away from the palm at "
            "q = 0, so their signs are not checked: look at the `--png` picture"
        )
    return lines, warnings, problems


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(description=__doc__.splitlines()[0])
    parser.add_argument("hand", help="built-in hand name or path to a spec.yaml")
    parser.add_argument("--png", help="draw the open and grasp poses to this PNG")
    parser.add_argument("--n-points", type=positive_int, default=2048)
    parser.add_argument(
        "--suggest", action="store_true", help="print the base, side and signs measured, as spec YAML"
    )
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
    lines, warnings, frame_problems = frame_report(hand)
    problems += frame_problems
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
    if args.suggest:
        print("\n".join(frame.suggestion(hand, frame.measure(hand))))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
