"""The universal hand: every physically meaningful joint across all supported end-effectors.

The paper's unified decoder predicts all of these joints at once; each hand selects the ones it has.
A hand's actuated (independent) joints map one-to-one onto names in this table; joints driven by a
coupling (mimic, tendon, linkage) are not listed, because they follow from their source joint.

Conventions: flexion is positive towards the palm; abduction/yaw is positive away from the middle
finger (towards the thumb for the index finger); revolute values are radians, prismatic values metres.
Grippers are hands too: their jaws carry the thumb (u=1) and index (u=2) labels, so a pinch by a
gripper and by a hand share semantics.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

FINGERS: tuple[str, ...] = ("palm", "thumb", "index", "middle", "ring", "little")
"""Finger index u of the semantic label (u, v): 0 palm, 1 thumb, 2 index, 3 middle, 4 ring, 5 little."""


@dataclass(frozen=True)
class UniversalJoint:
    name: str
    kind: Literal["revolute", "prismatic"]
    finger: int
    description: str


def _finger_joints(finger: str) -> tuple[UniversalJoint, ...]:
    u = FINGERS.index(finger)
    return (
        UniversalJoint(f"{finger}_cmc_flex", "revolute", u, f"{finger} metacarpal flexion (palm arching)"),
        UniversalJoint(f"{finger}_mcp_abd", "revolute", u, f"{finger} knuckle abduction (side-to-side)"),
        UniversalJoint(f"{finger}_mcp_flex", "revolute", u, f"{finger} knuckle flexion"),
        UniversalJoint(f"{finger}_pip_flex", "revolute", u, f"{finger} middle-joint flexion"),
        UniversalJoint(f"{finger}_dip_flex", "revolute", u, f"{finger} fingertip-joint flexion"),
    )


UNIVERSAL_JOINTS: tuple[UniversalJoint, ...] = (
    UniversalJoint("gripper_aperture", "prismatic", 0, "parallel-jaw opening, one jaw's travel"),
    UniversalJoint("gripper_knuckle", "revolute", 0, "linkage-gripper drive joint, closing positive"),
    UniversalJoint("palm_finger_spread", "revolute", 0, "rotation of opposing fingers about the palm normal"),
    UniversalJoint(
        "thumb_cmc_yaw", "revolute", 1, "thumb rotation into opposition (about the palm's long axis)"
    ),
    UniversalJoint("thumb_cmc_abd", "revolute", 1, "thumb base abduction away from the palm plane"),
    UniversalJoint("thumb_cmc_roll", "revolute", 1, "thumb roll about its own axis"),
    UniversalJoint("thumb_mcp_flex", "revolute", 1, "thumb knuckle flexion"),
    UniversalJoint("thumb_ip_flex", "revolute", 1, "thumb tip-joint flexion"),
    *_finger_joints("index"),
    *_finger_joints("middle"),
    *_finger_joints("ring"),
    *_finger_joints("little"),
)

UNIVERSAL_JOINT_NAMES: tuple[str, ...] = tuple(j.name for j in UNIVERSAL_JOINTS)
UNIVERSAL_INDEX: dict[str, int] = {name: i for i, name in enumerate(UNIVERSAL_JOINT_NAMES)}


def universal_table_markdown() -> str:
    """The table as Markdown, for the README and `lerobot-opfa hands joints`."""
    rows = ["| # | name | kind | finger | meaning |", "|---|---|---|---|---|"]
    rows += [
        f"| {i} | `{j.name}` | {j.kind} | {FINGERS[j.finger]} | {j.description} |"
        for i, j in enumerate(UNIVERSAL_JOINTS)
    ]
    return "\n".join(rows)
