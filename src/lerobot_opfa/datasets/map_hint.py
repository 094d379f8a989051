"""When a robot's entry names match no hand: the closest hand by joint structure and names, and a joint map
to start from (what `identify_hand`'s error prints)."""

from __future__ import annotations

import re

from lerobot_opfa.hands.registry import hand_ref
from lerobot_opfa.hands.spec import HandSpec
from lerobot_opfa.hands.universal import FINGERS

_SYNONYMS = {
    **dict.fromkeys(("side", "abduction", "spread", "lateral", "ab"), "abd"),
    **dict.fromkeys(("fwd", "forward", "flexion", "bend", "curl"), "flex"),
    "pinky": "little",
}
"""Words vendors use for the universal table's motions (a LEAP plugin's `mcp_side` is `mcp_abd`)."""


def _tokens(name: str) -> set[str]:
    return {_SYNONYMS.get(t, t) for t in re.split(r"[^a-z0-9]+", name.lower()) if t}


def _finger(name: str) -> str | None:
    return next((t for t in _tokens(name) if t in FINGERS[1:]), None)


def _structure(joint_fingers: list[str | None]) -> dict[str | None, int]:
    return {f: joint_fingers.count(f) for f in set(joint_fingers)}


def closest_hands(names: list[str], specs: list[HandSpec]) -> list[HandSpec]:
    """The hands whose joint structure (joints per finger, then joint count, then shared words) is closest to
    the entries'; several when they tie (LEAP and Allegro have the same joints)."""
    entries = _structure([_finger(n) for n in names if _finger(n)])

    def distance(spec: HandSpec) -> tuple[int, int, int]:
        fingers = _structure([_finger(u) for u in spec.joints.values()])
        per_finger = sum(abs(entries.get(f, 0) - fingers.get(f, 0)) for f in set(entries) | set(fingers) if f)
        words = set().union(*map(_tokens, names))
        shared = sum(len(words & (_tokens(j) | _tokens(u))) for j, u in spec.joints.items())
        return per_finger, abs(len(names) - len(spec.joints)), -shared

    best = min(map(distance, specs))
    return [s for s in specs if distance(s) == best]


def map_to_write(names: list[str], spec: HandSpec, alternatives: list[HandSpec] = ()) -> str:
    """A joint map for `spec` pairing each joint with the entry of its finger whose name shares the most
    words with it (in order where they tie): a start for the user to check line by line, as YAML."""
    free = list(names)
    others = (
        f"  # or {', '.join(a.name for a in alternatives)}: the same joint structure" if alternatives else ""
    )
    lines = [f"hand: {hand_ref(spec)}{others}", "joints:"]
    for joint, universal in spec.joints.items():
        finger = universal.split("_")[0]
        candidates = [n for n in free if _finger(n) == finger] or free
        if not candidates:
            break
        best = max(candidates, key=lambda n: len(_tokens(n) & (_tokens(joint) | _tokens(universal))))
        free.remove(best)
        lines.append(f"  {best}: {joint}")
    return "\n".join(lines)
