"""Where a hand's fingers point, where its palm faces, which hand it is and which way each flexion joint
curls, measured from what does not depend on the spec's joint signs, so that the signs can be judged
against it (a palm measured from the flexions themselves turns a wrong sign into a wrong frame, whose
"fix" mirrors the hand).

All at q = 0 (clipped into the limits). The fingers point from each finger's root link to its tip, the
thumb left out (many thumbs stand sideways at rest). The palm is the side the fingers curl to: the side
their flexion joints' ranges reach farther, since a finger curls far towards the palm and bends back
little. The hand is a right hand when its thumb lies on -x of the frame these two directions make, or,
where the thumb stands between the other fingers (Unitree's Dex3), when the first of them (the index) does. A
flexion joint's sign is right when its universal sense moves the fingertip towards the palm, a thumb's
towards the other fingertips.
"""

from __future__ import annotations

import itertools
import json
import re
from dataclasses import dataclass

import numpy as np
import torch

from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.spec import BaseFrame, HandSpecError
from lerobot_opfa.hands.universal import FINGERS, UNIVERSAL_INDEX, UNIVERSAL_JOINTS

THUMB = 1
STEP = 0.05
"""Share of a joint's range moved to measure which way it carries its fingertip."""
CLEAR = 0.3
"""Cosine between a flexion's motion and its target below which its sense is not told either way."""
PALM_CLEAR = 0.2
"""Share of the flexion ranges' reach that must agree on one side for the palm to be told."""
THUMB_CLEAR = 0.005
"""Metres the root of the finger that tells the hand (the thumb, or a centred thumb's index) must lie off
the other fingers' roots' centre, across the palm."""
THUMB_OFF_CENTRE = 0.35
"""Share of the other fingers' half-width across the palm that the thumb's root must lie off their centre
to tell the hand; nearer the centre, the first finger after the thumb tells it."""
SNAP_DEG = 30.0
"""A measured frame this close to a quarter-turn frame is taken as that frame (CAD tools use those)."""
ORIGIN_TOLERANCE = 0.05
"""Metres the hand may lie from its frame's origin (the wrist flange), or reach behind it."""


@dataclass(frozen=True)
class HandFrame:
    fingers_point: np.ndarray
    """Unit vector in the hand frame: the mean direction from the fingers' roots to their tips."""
    pointing_fingers: tuple[int, ...]
    """The fingers (u) it was measured from."""
    palm_faces: np.ndarray | None
    """Unit vector orthogonal to `fingers_point`; None for a gripper, or where the ranges do not tell."""
    side: str | None
    """'right' or 'left' from the thumb's side; None where there is no thumb or no palm."""
    flexion: dict[str, float]
    """Flexion joint -> cosine between its universal sense's fingertip motion and the palm (a thumb's:
    the other fingertips)."""
    nearest: float
    """Metres from the origin to the nearest point of the hand in its open pose."""
    behind: float
    """Metres the hand reaches behind the origin (along -z)."""
    wrist: np.ndarray
    """Where the origin belongs: behind the palm's centre, level with the back end of the hand."""
    across: tuple[int, ...] = ()
    """The fingers other than the thumb in the order their tips lie across the palm, from the thumb's side
    (from -x where there is no thumb); empty where the palm is not told."""
    side_told_by: str = "thumb"
    """The finger whose side across the palm told `side`: the thumb, or the index where the thumb is
    centred."""


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-12)


def finger_of(universal: str) -> int:
    return UNIVERSAL_JOINTS[UNIVERSAL_INDEX[universal]].finger


def measure(hand: HandModel) -> HandFrame:
    """The hand's frame, side and flexion senses, from its links, tips and ranges at q = 0."""
    if not hand.fingertip_links:
        raise HandSpecError(
            hand.spec.path, "links", "no link is labelled as a finger, so nothing says where the hand "
            "points: name each finger's first joint or link under `fingers:`, or label its links [finger, "
            "segment]",
        )  # fmt: skip
    rest = torch.zeros(hand.dof, dtype=torch.float64).clamp(hand.lower.double(), hand.upper.double())
    lower, upper = hand.lower.double(), hand.upper.double()
    steps = STEP * (upper - lower) * torch.where(rest + STEP * (upper - lower) <= upper, 1.0, -1.0)
    rows = rest.repeat(hand.dof + 1, 1)
    rows[1:] += torch.diag(steps)
    tips_all = hand.fingertip_positions(rows.to(hand.dtype)).double().cpu().numpy()
    tips, rate = tips_all[0], (tips_all[1:] - tips_all[:1]) / steps.numpy()[:, None, None]
    fingers = [hand.spec.links[link][0] for link in hand.fingertip_links]

    roots: dict[int, tuple[int, str]] = {}
    for link in hand.link_names:
        u, v = hand.spec.links[link]
        if u > 0 and (u not in roots or v < roots[u][0]):
            roots[u] = (v, link)
    root_links = [roots[u][1] for u in fingers]
    root_at = hand.link_poses(rest[None].to(hand.dtype), root_links)[0, :, :3, 3].double().cpu().numpy()

    others = [i for i, u in enumerate(fingers) if u != THUMB]
    pointing = others if others and hand.spec.kind == "hand" else list(range(len(fingers)))
    point = _unit(sum(_unit(tips[i] - root_at[i]) for i in pointing))
    cloud = hand.point_cloud(hand.pose("open")[None], 512)
    points, labels = cloud.points[0].double().cpu().numpy(), cloud.labels[0, :, 0].cpu().numpy()
    palm_centre = points[labels == 0].mean(0) if (labels == 0).any() else points.mean(0)
    wrist = palm_centre + ((points @ point).min() - palm_centre @ point) * point
    measured = dict(
        fingers_point=point,
        pointing_fingers=tuple(fingers[i] for i in pointing),
        nearest=float(np.linalg.norm(points, axis=1).min()),
        behind=max(0.0, float(-points[:, 2].min())),
        wrist=wrist,
    )
    if hand.spec.kind != "hand" or not others:
        return HandFrame(palm_faces=None, side=None, flexion={}, **measured)

    flexions = [
        (j, joint, fingers.index(finger_of(u)))
        for j, (joint, u) in enumerate(zip(hand.joint_names, hand.universal_names, strict=True))
        if u.endswith("_flex") and finger_of(u) in fingers
    ]
    # Each finger flexion's fingertip motion per radian, weighted by how much farther its range reaches
    # one way than the other from rest: the sum points to where the fingers curl.
    reach = (upper - rest - (rest - lower)).numpy()
    curls = np.array([reach[j] * rate[j, i] for j, _, i in flexions if fingers[i] != THUMB]).reshape(-1, 3)
    curl = curls.sum(0) - (curls.sum(0) @ point) * point
    if np.linalg.norm(curl) <= PALM_CLEAR * np.linalg.norm(curls, axis=1).sum():
        return HandFrame(palm_faces=None, side=None, flexion={}, **measured)
    palm = _unit(curl)

    side, told_by = None, "thumb"
    if THUMB in fingers:
        at = (root_at - root_at[others].mean(0)) @ np.cross(palm, point)
        first = min(others, key=lambda i: fingers[i])
        off = at[fingers.index(THUMB)]
        if abs(off) < THUMB_OFF_CENTRE * np.ptp(at[others]) / 2:
            off, told_by = at[first], f"{FINGERS[fingers[first]]} finger"
        side = None if abs(off) < THUMB_CLEAR else "right" if off < 0 else "left"
    across_palm = tips[others] @ np.cross(palm, point) * (-1.0 if side == "left" else 1.0)
    across = tuple(fingers[others[i]] for i in np.argsort(across_palm))
    fingertips = tips[others].mean(0)
    flexion = {}
    for j, joint, i in flexions:
        target = palm if fingers[i] != THUMB else _unit(fingertips - tips[i])
        flexion[joint] = float(_unit(float(hand.universal_sign[j]) * rate[j, i]) @ target)
    return HandFrame(
        palm_faces=palm, side=side, side_told_by=told_by, across=across, flexion=flexion, **measured
    )


def signs_to_flip(frame: HandFrame) -> list[str]:
    """Flexion joints whose universal sense carries the fingertip away from the palm (the fingertips)."""
    return [joint for joint, cosine in frame.flexion.items() if cosine < -CLEAR]


def fingers_out_of_order(frame: HandFrame) -> bool:
    """Whether the fingers' tips lie across the palm in another order than index, middle, ring, little
    from the thumb's side (or, without a thumb, either way): two fingers' joints named the other's."""
    order = list(frame.across)
    return order != sorted(order) and (frame.side is not None or order != sorted(order, reverse=True))


def unclear_flexions(frame: HandFrame) -> list[str]:
    return [joint for joint, cosine in frame.flexion.items() if abs(cosine) <= CLEAR]


def rpy_matrix(rpy: tuple[float, float, float]) -> np.ndarray:
    """URDF's roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy), np.sin(rpy)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def matrix_rpy(matrix: np.ndarray) -> tuple[float, float, float]:
    pitch = float(np.arcsin(np.clip(-matrix[2, 0], -1.0, 1.0)))
    if abs(matrix[2, 0]) > 1 - 1e-9:  # gimbal lock: the roll is folded into the yaw
        return 0.0, pitch, float(np.arctan2(-matrix[0, 1], matrix[1, 1]))
    return float(np.arctan2(matrix[2, 1], matrix[2, 2])), pitch, float(np.arctan2(matrix[1, 0], matrix[0, 0]))


def _quarter_turns() -> list[np.ndarray]:
    """The 24 rotations that map axes onto axes."""
    turns = []
    for order in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            matrix = np.zeros((3, 3))
            matrix[list(order), range(3)] = signs
            if np.linalg.det(matrix) > 0:
                turns.append(matrix)
    return turns


def origin_is_off(frame: HandFrame) -> bool:
    return frame.nearest > ORIGIN_TOLERANCE or frame.behind > ORIGIN_TOLERANCE


def suggested_base(hand: HandModel, frame: HandFrame) -> BaseFrame | None:
    """The spec's `base` turned so that the fingers point along +z and the palm faces +y, its origin moved
    to the wrist where it lies off the hand; None where the palm is not told."""
    if frame.palm_faces is None:
        return None
    y, z = frame.palm_faces, frame.fingers_point
    turn = np.stack([np.cross(y, z), y, z], 1)  # the measured axes, in the spec's hand frame
    nearest = max(_quarter_turns(), key=lambda q: float(np.trace(q.T @ turn)))
    angle = np.degrees(np.arccos(np.clip((np.trace(nearest.T @ turn) - 1) / 2, -1.0, 1.0)))
    old = rpy_matrix(hand.spec.base.rpy)
    rpy = tuple(round(a, 10) + 0.0 for a in matrix_rpy(old @ (nearest if angle <= SNAP_DEG else turn)))
    xyz = np.array(hand.spec.base.xyz) + (old @ frame.wrist if origin_is_off(frame) else 0.0)
    return BaseFrame(hand.spec.base.link, tuple(round(float(v), 4) + 0.0 for v in xyz), rpy)


def _name(name: str) -> str:
    return name if re.fullmatch(r"[A-Za-z0-9_.\-]+", name) else json.dumps(name)


def base_yaml(base: BaseFrame) -> str:
    link = "" if base.link is None else f"link: {json.dumps(base.link)}, "
    return f"base: {{{link}xyz: {list(base.xyz)}, rpy: {list(base.rpy)}}}"


def suggestion(hand: HandModel, frame: HandFrame) -> list[str]:
    """YAML lines for the spec: the base, the side where it is a left hand, and the joints with the signs
    the flexions need (the other joints' signs as the spec gives them)."""
    lines = ["# measured by `hands check --suggest`: paste over the spec's own fields"]
    if frame.side == "left":
        lines.append("side: left")
    base = suggested_base(hand, frame)
    if base is not None:
        lines.append(base_yaml(base))
    flip = set(signs_to_flip(frame))
    lines.append("joints:")
    for joint, universal in hand.spec.joints.items():
        sign = hand.spec.signs.get(joint, 1.0) * (-1.0 if joint in flip else 1.0)
        value = universal if sign > 0 else f"{{universal: {universal}, sign: -1}}"
        lines.append(f"  {_name(joint)}: {value}")
    return lines
