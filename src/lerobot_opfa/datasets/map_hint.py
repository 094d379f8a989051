"""When a robot's entry names match no hand: the closest hand by joint structure and names, and a joint map
to start from (what `identify_hand`'s error prints).

Entry names are read as words, whatever their case (`kLeftHandThumb0`, `right_hand.ring_mcp_side.pos`): a
side, a finger, a motion. Only an entry that names a finger is proposed for a hand joint (an arm's
`left_shoulder_pan.pos` never is); a two-armed robot gets a hand per side, each a slot of one map. Where
the dataset records its entries' ranges, the ranges pick between hands of the same structure and names (the
one whose limits they fit) and propose the units of entries that plainly are not the spec's (degrees,
0..1000).
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

from lerobot.utils.constants import OBS_STATE

from lerobot_opfa.datasets.io import read_json
from lerobot_opfa.datasets.joint_map import entry_side, entry_words, fits_limits
from lerobot_opfa.hands.registry import hand_ref, load_hand
from lerobot_opfa.hands.spec import HandSpec

_SYNONYMS = {
    **dict.fromkeys(("side", "abduction", "spread", "lateral", "ab"), "abd"),
    **dict.fromkeys(("fwd", "forward", "flexion", "bend", "curl"), "flex"),
    **dict.fromkeys(("rot", "rotate", "rotation", "opposition"), "yaw"),
    **dict.fromkeys(("grasp", "jaw"), "gripper"),
    "pinky": "little",
}
"""Vendors' words for the universal table's (a LEAP plugin's `mcp_side` is `mcp_abd`, a Unitree G1's
`ThumbRotation` is `thumb_yaw`, a LeRobot arm's `gripper` is a gripper's jaw)."""

FINGER_WORDS = ("thumb", "index", "middle", "ring", "little", "gripper")
"""The first words of the universal joints' names: what an entry must name to be proposed for a joint of
that finger (a palm joint is left to the user: `palm` also names wrist poses)."""

UNITS_FACTOR = 3.0
"""A recorded range this many times wider than a joint's range is in other units (degrees, 0..1000)."""

DEGREE = math.pi / 180
MOTOR_END = 1e-6
"""How near 0 or 1 a 0..1 motor command held at an end records."""
CHECK = "check"
"""The word that marks a hint's line whose sense or units the recorded ranges cannot decide."""


def _words(name: str) -> list[str]:
    """`kLeftHandThumb0` -> k, left, hand, thumb, 0; `right_hand.ring_mcp_side.pos` -> right, hand, ring,
    mcp, abd, pos (vendor words as the universal table's)."""
    return [_SYNONYMS.get(word, word) for word in entry_words(name)]


def _meaning(name: str) -> set[str]:
    """An entry's or a joint's words but its side (a gripper's `left_knuckle` is not a left hand's)."""
    words = _words(name)
    lead = words[:1] if words[:1] in (["l"], ["r"]) else []
    return set(words) - {"left", "right", *lead}


def _finger(name: str) -> str | None:
    return next((w for w in _words(name) if w in FINGER_WORDS), None)


def _joint_finger(universal: str) -> str:
    return universal.split("_")[0]


def hand_sides(names: list[str]) -> dict[str | None, list[str]]:
    """The entries of each side when both sides have entries that name a finger (a two-armed robot), else
    all of them under None."""
    by_side: dict[str | None, list[str]] = {}
    for name in names:
        by_side.setdefault(entry_side(name), []).append(name)
    handed = [s for s in ("left", "right") if any(map(_finger, by_side.get(s, [])))]
    return {s: by_side[s] for s in handed} if len(handed) > 1 else {None: list(names)}


def _shared(entry: str, joint: str, universal: str) -> int:
    """Words an entry shares with a spec joint's name plus those it shares with its universal name."""
    words = _meaning(entry)
    return len(words & _meaning(joint)) + len(words & _meaning(universal))


def _pairs(names: list[str], spec: HandSpec) -> dict[str, str]:
    """Spec joint -> the entry proposed for it: an entry of its finger, the most shared words first (in the
    spec's, then the entries' order where they tie); joints whose finger no entry names are left out."""
    options = [
        (joint, entry)
        for joint, universal in spec.joints.items()
        for entry in names
        if _finger(entry) == _joint_finger(universal)
    ]
    options.sort(key=lambda o: -_shared(o[1], o[0], spec.joints[o[0]]))
    pairs: dict[str, str] = {}
    for joint, entry in options:
        if joint not in pairs and entry not in pairs.values():
            pairs[joint] = entry
    return {j: pairs[j] for j in spec.joints if j in pairs}


def _likeness(names: list[str], spec: HandSpec) -> tuple[int, int, int]:
    """(joints per finger apart, joint count apart, minus the words the proposed pairs share and the entries
    share with the hand's name): smaller is closer."""
    entries = [n for n in names if _finger(n)]
    mine, theirs = Counter(map(_finger, entries)), Counter(map(_joint_finger, spec.joints.values()))
    per_finger = sum(((mine - theirs) + (theirs - mine)).values())
    shared = sum(_shared(e, j, spec.joints[j]) for j, e in _pairs(names, spec).items())
    brand = {w for w in _words(spec.name) if w.isalpha() and len(w) > 2}
    named = len(brand & set().union(*map(_meaning, names)))
    return per_finger, abs(len(entries) - len(spec.joints)), -(shared + named)


def closest_hands(
    names: list[str], specs: list[HandSpec], ranges: dict[str, tuple[float, float]] | None = None
) -> list[HandSpec]:
    """The hands closest to the entries by structure (joints per finger, then joint count), then names
    (`_likeness`), then, where `ranges` are known, the fewest entries that fit the joint's limits in no plain
    units; several when they tie (LEAP and Allegro have the same joints under the same names)."""
    likeness = {s.path: _likeness(names, s) for s in specs}
    best = min(likeness.values())
    tied = [s for s in specs if likeness[s.path] == best]
    if ranges and len(tied) > 1:
        misfits = {s.path: _misfits(names, s, ranges) for s in tied}
        tied = [s for s in tied if misfits[s.path] == min(misfits.values())]
    return tied


def recorded_ranges(root: Path | str | None, names: list[str]) -> dict[str, tuple[float, float]]:
    """Per state entry, its (min, max) from the dataset's `meta/stats.json`; empty where it has none."""
    path = Path(root) / "meta" / "stats.json" if root is not None else None
    if path is None or not path.is_file():
        return {}
    stats = read_json(path).get(OBS_STATE, {})
    low, high = stats.get("min"), stats.get("max")
    if not isinstance(low, list) or not isinstance(high, list) or not len(low) == len(high) == len(names):
        return {}
    return {n: (float(lo), float(hi)) for n, lo, hi in zip(names, low, high, strict=True)}


def _limits(spec: HandSpec) -> dict[str, tuple[float, float]]:
    """Spec joint -> (lower, upper): the model's limits, in the spec's units."""
    hand = load_hand(hand_ref(spec))
    lower, upper = hand.lower.tolist(), hand.upper.tolist()
    return {j: (lower[i], upper[i]) for i, j in enumerate(hand.joint_names)}


def _misfits(names: list[str], spec: HandSpec, ranges: dict[str, tuple[float, float]]) -> int:
    """Proposed entries whose recorded range fits the joint's limits neither as it is, nor in degrees, nor
    the other way round: a sign that the robot carries another hand."""
    limits = _limits(spec)
    return sum(
        not any(fits_limits(ranges[e], limits[j], s) for s in (1.0, -1.0, DEGREE, -DEGREE))
        for j, e in _pairs(names, spec).items()
        if e in ranges
    )


def units_from_range(
    recorded: tuple[float, float], limits: tuple[float, float]
) -> tuple[float, float] | None:
    """(scale, offset) taking an entry's recorded range onto a joint's limits where they plainly differ: -1
    where only the negated range fits, degrees where the range is many times the joint's and fits in degrees,
    else the range stretched onto the limits; None where it fits as it is or is in the spec's units."""
    low, high = recorded
    if high == low or fits_limits(recorded, limits):
        return None
    if fits_limits(recorded, limits, -1.0):
        return -1.0, 0.0
    if high - low <= UNITS_FACTOR * (limits[1] - limits[0]):
        return None
    for scale in (DEGREE, -DEGREE):
        if fits_limits(recorded, limits, scale):
            return scale, 0.0
    scale = (limits[1] - limits[0]) / (high - low)
    return scale, limits[0] - scale * low


def sense_undecided(recorded: tuple[float, float], limits: tuple[float, float]) -> bool:
    """Whether a moving entry's recorded range fits the joint's limits both as it is and negated: the ranges
    cannot tell the joint's sense (a mirrored left hand's entries may read either way)."""
    return recorded[1] > recorded[0] and fits_limits(recorded, limits) and fits_limits(recorded, limits, -1.0)


def motor_units(recorded: list[tuple[float, float]]) -> bool:
    """Whether every entry of a hand lies within 0..1 and reaches one end of it: a 0..1 motor command held
    at an end (Unitree's converters record the G1's Inspire so, 1 = open), or radians that happen to lie
    there. The ranges tell neither that apart nor which end is open: a hint proposes motor units and says
    both on each line."""
    ends = [low <= MOTOR_END or high >= 1.0 - MOTOR_END for low, high in recorded]
    return bool(recorded) and all(fits_limits(r, (0.0, 1.0)) for r in recorded) and all(ends)


def map_to_write(
    sides: dict[str | None, tuple[list[str], HandSpec, list[HandSpec]]],
    ranges: dict[str, tuple[float, float]] | None = None,
) -> str:
    """A joint map pairing each joint of a side's hand with an entry of its finger (`_pairs`), with the
    units the recorded `ranges` suggest: a start for the user to check line by line, as YAML. `sides`: per
    side (None: a one-handed robot's), its entries, its closest hand and the hands as close; a two-armed
    robot's map holds one slot per side."""
    hands = {side: _hand_lines(*hand, ranges) for side, hand in sides.items()}
    lines = []
    if any(scaled for _, scaled in hands.values()):
        lines.append(
            "# scale/offset: inferred from the recorded ranges (meta/stats.json) and the joint limits; "
            "check them, and each sign"
        )
    if any(CHECK in line for hand, _ in hands.values() for line in hand):
        lines.append(f"# lines marked '{CHECK}': the recorded ranges cannot decide their sense or units")
    if None in hands:
        return "\n".join(lines + hands[None][0])
    lines.append("slots:  # one per hand")
    for side, (hand, _) in hands.items():
        lines += [f"  - side: {side}", *("    " + line for line in hand)]
    return "\n".join(lines)


def _hand_lines(
    names: list[str],
    spec: HandSpec,
    alternatives: list[HandSpec],
    ranges: dict[str, tuple[float, float]] | None,
) -> tuple[list[str], bool]:
    """The `hand` and `joints` lines of one hand's map, and whether any joint has inferred units."""
    pairs = _pairs(names, spec)
    limits = _limits(spec) if ranges else {}
    recorded = {j: ranges[e] for j, e in pairs.items() if ranges and e in ranges}
    motor = motor_units(list(recorded.values()))
    units = {
        j: (limits[j][1] - limits[j][0], limits[j][0]) if motor else units_from_range(r, limits[j])
        for j, r in recorded.items()
    }
    others = f"  # or {', '.join(a.name for a in alternatives)}: as close" if alternatives else ""
    lines = [f"hand: {hand_ref(spec)}{others}", "joints:"]
    for joint, entry in pairs.items():
        scaled = units.get(joint)
        value = f"{{joint: {joint}, scale: {scaled[0]:.6g}, offset: {scaled[1]:.6g}}}" if scaled else joint
        if motor and scaled:
            value += (
                f"  # {CHECK}: a 0..1 motor command with 0 at the lower limit; if 1 is there instead (an "
                f"open hand's 1), scale: {-scaled[0]:.6g}, offset: {limits[joint][1]:.6g}; radians: no scale"
            )
        elif scaled is None and joint in recorded and sense_undecided(recorded[joint], limits[joint]):
            value += (
                f"  # {CHECK}: the recorded range fits this joint either way round (scale -1 if mirrored)"
            )
        lines.append(f"  {entry}: {value}")
    missing = [j for j in spec.joints if j not in pairs]
    if missing:
        lines.append(f"  # no entry names the finger of: {', '.join(missing)}")
    return lines, any(units.values())
