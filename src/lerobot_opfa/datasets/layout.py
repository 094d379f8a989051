"""What a LeRobotDataset's state/action columns mean for lerobot-opfa.

Two layouts are understood, both read from `meta/info.json` feature names:
- native: one hand; `observation.state` / `action` = wrist entries, then that hand's actuated joints
  (names from its spec, any order);
- merged (written by `lerobot-opfa dataset merge`): the body entries, then per hand slot the universal
  joints and optionally the cached GaLR latents `z0..` (each prefixed by the slot's side on a two-handed
  robot: `left.index_mcp_flex`, `left.z0`); `observation.embodiment` names the hands its ids index, one id
  per slot.

A dataset of a user's hand records its spec (path and hash) in `meta/opfa.json`, so every later command finds
the hand from the dataset alone; `meta/info.json` keeps a copy, which LeRobot's editing tools keep too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa.datasets.io import OPFA_META_FILE, embedded_record, read_json
from lerobot_opfa.datasets.joint_map import HANDS_SEPARATOR, SIDES, JointMap, JointMapError, joint_of
from lerobot_opfa.datasets.map_hint import closest_hands, hand_sides, map_to_write, recorded_ranges
from lerobot_opfa.features import OBS_EMBODIMENT
from lerobot_opfa.hands.registry import builtin_hands, hand_ref, load_spec
from lerobot_opfa.hands.spec import HandSpec
from lerobot_opfa.hands.universal import UNIVERSAL_JOINT_NAMES

LATENT_PREFIX = "z"
LATENT_ROBOT_TYPE = "opfa_latent"
"""The `robot_type` of a `policy latent-dataset` output: state and action are body + z, not joints."""


class JointNameError(ValueError):
    """A dataset's joint names do not match the hand spec it is read with."""


@dataclass(frozen=True)
class DatasetLayout:
    kind: str
    """`native` or `merged`."""
    embodiments: list[str]
    hand_refs: list[str]
    """Per embodiment, what `load_hand` takes: a built-in name or a user hand's spec path."""
    wrist_names: list[str]
    """The state's body entries: every entry that is not a hand joint (a wrist pose, an arm's joints)."""
    joint_maps: list[JointMap] = field(default_factory=list)
    """Per embodiment, how its robot's state/action vectors hold the body entries and the hand's joints."""
    latent_dim: int = 0
    """merged: width of the cached latents (0: none cached)."""
    galr_fingerprint: str | None = None
    action_body_names: list[str] | None = None
    """The action's body entries where they differ from the state's (end-effector deltas against arm
    joints); None: the same."""
    robots: list[list[int]] = field(default_factory=list)
    """Per joint map (a robot), the embodiment each of its hand slots holds."""
    sides: list[str | None] = field(default_factory=lambda: [None])
    """The side of each hand slot ([None]: one hand, its side unsaid)."""


def feature_names(features: dict, key: str) -> list[str]:
    names = features[key].get("names")
    if isinstance(names, dict):  # {"motors": [...]} style
        names = next(iter(names.values()))
    if not names:
        raise ValueError(f"feature '{key}' has no names in meta/info.json; lerobot-opfa maps joints by name")
    return [str(n) for n in names]


def latent_names(latent_dim: int) -> list[str]:
    return [f"{LATENT_PREFIX}{i}" for i in range(latent_dim)]


def merged_names(body: list[str], sides: list[str | None], latent_dim: int) -> list[str]:
    """A merged dataset's state/action entries: the body's, then per slot its universal joints and z."""
    hand = [*UNIVERSAL_JOINT_NAMES, *latent_names(latent_dim)]
    return [*body, *(f"{side}.{name}" if side else name for side in sides for name in hand)]


def _hand_candidates(hands: list[str] | None) -> list[str]:
    """Hand names or spec paths to match against (default: the built-in hands)."""
    return list(hands) if hands else list(builtin_hands())


def identify_hand(
    names: list[str], robot_type: str | None, hands: list[str] | None = None, root: Path | str | None = None
) -> HandSpec:
    """The hand whose actuated joints a native state vector holds under their own names: `robot_type` when
    it names a hand, else the one candidate whose joints all appear. Otherwise the error names the closest
    hand by joint structure and names (per side for a two-armed robot) and the joint map to write, with
    units from the ranges the dataset at `root` records."""
    specs = list({s.path: s for s in map(load_spec, _hand_candidates(hands))}.values())
    joints = {joint_of(n) for n in names} | set(names)
    named = [s for s in specs if s.name == robot_type]
    if named and set(named[0].actuated_joints) <= joints:
        return named[0]
    matches = [] if named else [s for s in specs if set(s.actuated_joints) <= joints]
    if matches:
        best = max(len(s.actuated_joints) for s in matches)
        widest = [s for s in matches if len(s.actuated_joints) == best]
        if len(widest) == 1:
            return widest[0]
        raise JointNameError(
            f"joint names {names} fit several hands ({', '.join(s.name for s in widest)}); set the dataset's "
            "robot_type to the hand's name"
        )
    ranges = recorded_ranges(root, names)
    closest, sides = [], {}
    for side, entries in hand_sides(names).items():
        hand, *alternatives = named or closest_hands(entries, specs, ranges)
        missing = [j for j in hand.actuated_joints if j not in joints]
        unknown = [n for n in entries if joint_of(n) not in hand.joints]
        closest.append(
            (f"{side} entries: " if side else "")
            + ", ".join(repr(s.name) for s in [hand, *alternatives])
            + f" ({len(hand.joints)} joints; missing {missing}, unknown {unknown})"
        )
        sides[side] = (entries, hand, alternatives)
    whose = f"hand '{robot_type}'" if named else "any registered hand"
    raise JointNameError(
        f"the state/action entries ({len(names)}: {', '.join(map(repr, names[:4]))}, ...) are not named "
        f"after the joints of {whose}; closest by joint structure and names: {'; '.join(closest)}. "
        "Write a joint map (docs/usage.md) and pass it "
        "(merge: --joint-maps FILE; training: --policy.joint_map=FILE); a start, to check line by line:\n"
        + map_to_write(sides, ranges)
    )


def opfa_record(root: Path | str | None) -> dict:
    """What lerobot-opfa recorded about a dataset: `meta/opfa.json`, or the copy `meta/info.json` keeps
    (all that is left once LeRobot's editing tools rewrote `meta/`); empty for a dataset it did not write."""
    if root is None:
        return {}
    meta = Path(root) / OPFA_META_FILE
    return read_json(meta) if meta.is_file() else embedded_record(root) or {}


def lost_record(features: dict, record: dict, root: Path | str | None) -> str | None:
    """Why a dataset cannot be read without the record it lost, or None: a merged dataset's cached latents
    are of a GaLR only its record (`opfa_record`) names (a dataset merged before `meta/info.json` kept a copy,
    then edited with LeRobot's tools, which drop `meta/opfa.json`)."""
    names = feature_names(features, OBS_STATE) if OBS_STATE in features else []
    z0 = latent_names(1)[0]
    cached = OBS_EMBODIMENT in features and any(n == z0 or n.endswith(f".{z0}") for n in names)
    if not cached or root is None or record.get("galr_fingerprint"):
        return None
    return (
        f"{root} holds latents cached by `lerobot-opfa dataset merge --galr`, but not its {OPFA_META_FILE}, "
        "which names the GaLR that cached them (LeRobot's editing tools drop it from datasets merged by an "
        "older lerobot-opfa): merge the inputs again (and edit that merge)"
    )


def hand_entry(spec: HandSpec) -> dict[str, str]:
    """How a dataset records a user hand."""
    return {"spec": str(spec.path), "sha256": spec.sha256}


def recorded_hands(root: Path | str | None, record: dict) -> dict[str, str]:
    """User hands a dataset's record names, name -> spec path, each checked against its recorded hash."""
    hands = {}
    for name, entry in record.get("hands", {}).items():
        path = Path(entry["spec"])
        if not path.is_file():
            raise ValueError(
                f"{root}: its hand '{name}' was recorded from {path}, which is not there; put the spec back "
                "there (or pass it with --hands)"
            )
        if load_spec(path).sha256 != entry["sha256"]:
            raise ValueError(
                f"{root}: the spec or model of hand '{name}' ({path}) changed since the dataset was "
                "recorded; record the demos again"
            )
        hands[name] = str(path)
    return hands


def read_layout(
    features: dict,
    robot_type: str | None = None,
    root: Path | str | None = None,
    hands=None,
    joint_map: JointMap | None = None,
) -> DatasetLayout:
    """The layout of a dataset from its features and what `meta/opfa.json` under `root` records. `hands`:
    the hands (names or spec paths) it may hold besides the built-ins and the ones it records; `joint_map`:
    how a native dataset holds its hand, when its entries are not named after the spec's joints."""
    record = opfa_record(root)
    lost = lost_record(features, record, root)
    if lost:
        raise ValueError(lost)
    # The hands the dataset records come first: a user's hand named like a built-in is the user's.
    candidates = [*recorded_hands(root, record).values(), *_hand_candidates(hands)]
    names = feature_names(features, OBS_STATE)
    actions = feature_names(features, ACTION) if ACTION in features else names
    if OBS_EMBODIMENT in features:
        if actions != names:
            raise JointNameError(
                f"a merged dataset's '{ACTION}' and '{OBS_STATE}' must name the same entries"
            )
        embodiments = feature_names(features, OBS_EMBODIMENT)
        first, universal = UNIVERSAL_JOINT_NAMES[0], list(UNIVERSAL_JOINT_NAMES)
        starts = [i for i, n in enumerate(names) if n == first or n.endswith(f".{first}")]
        if not starts:
            raise JointNameError(f"a merged dataset's state must hold the universal joints {universal}")
        wrist, sides = names[: starts[0]], [names[i].removesuffix(first).rstrip(".") or None for i in starts]
        latent_dim = (len(names) - len(wrist)) // len(sides) - len(universal)
        if names != merged_names(wrist, sides, latent_dim):
            raise JointNameError(
                f"unexpected entries after the body {wrist}: a merged dataset holds per hand slot the "
                f"universal joints, then z0.. ({', '.join(names[len(wrist) : len(wrist) + 3])} ...)"
            )
        specs = {}
        for spec in map(load_spec, candidates):
            specs.setdefault(spec.name, spec)
        unknown = [h for h in embodiments if h not in specs]
        if unknown:
            raise ValueError(
                f"{root}: hand(s) {unknown} are neither built in nor recorded by the dataset (meta/opfa.json)"
            )
        refs = [hand_ref(specs[h]) for h in embodiments]
        robots = record.get("robots") or [[i] for i in range(len(embodiments))]
        if len(robots[0]) != len(sides):
            raise ValueError(
                f"{root}: a merge of two-handed robots that lost its {OPFA_META_FILE} (which robots it "
                "holds); merge the inputs again"
            )
        maps = [_recorded_map(record, [specs[embodiments[e]] for e in robot], wrist) for robot in robots]
        fingerprint = record.get("galr_fingerprint")
        return DatasetLayout(
            "merged", embodiments, refs, wrist, maps, latent_dim, fingerprint, robots=robots, sides=sides
        )
    if joint_map is None and "joint_map" in record:  # a dataset that says which entries are which hand
        joint_map = JointMap.from_dict(record["joint_map"], f"the joint map recorded in {OPFA_META_FILE}")
    if joint_map is None:
        joint_map = _two_armed_map(robot_type, names, actions, candidates)
    if joint_map is None:
        spec = identify_hand(names, robot_type, candidates, root)
        joint_map = JointMap.named_after(spec, names, actions)
    else:
        joint_map = joint_map.bind(names, actions)
        joint_map.check_robot_type(robot_type)
    specs = {}
    for slot in joint_map.slots:
        specs.setdefault(slot.spec.name, slot.spec)
    embodiments = list(specs)
    state_body, action_body = joint_map.body_names(OBS_STATE), joint_map.body_names(ACTION)
    return DatasetLayout(
        "native",
        embodiments,
        [hand_ref(spec) for spec in specs.values()],
        state_body,
        [joint_map],
        action_body_names=None if action_body == state_body else action_body,
        robots=[[embodiments.index(slot.spec.name) for slot in joint_map.slots]],
        sides=[slot.side for slot in joint_map.slots],
    )


def _two_armed_map(
    robot_type: str | None, names: list[str], actions: list[str], candidates: list[str]
) -> JointMap | None:
    """The map of a two-armed robot named by its hands (`inspire+xhand`, as the simulated rig records it)
    whose entries name each side's joints (`left_<joint>.pos`); None for any other dataset."""
    hands = (robot_type or "").split(HANDS_SEPARATOR)
    specs = {}
    for spec in map(load_spec, candidates):
        specs.setdefault(spec.name, spec)
    if len(hands) != len(SIDES) or not set(hands) <= set(specs):
        return None
    try:
        return JointMap.named_after_arms(
            dict(zip(SIDES, (specs[h] for h in hands), strict=True)), names, actions
        )
    except JointMapError:
        return None


def _recorded_map(record: dict, specs: list[HandSpec], wrist: list[str]) -> JointMap:
    """How a robot of a merged dataset (its slots' hands `specs`) laid out its vectors: the map its input was
    merged with, or (a dataset of this package's simulator, one hand) the body entries, then the joints
    under their own names."""
    robot = HANDS_SEPARATOR.join(spec.name for spec in specs)
    recorded = record.get("joint_maps", {}).get(robot)
    if recorded is not None:
        return JointMap.from_dict(recorded, f"the joint map of '{robot}' recorded in {OPFA_META_FILE}")
    (spec,) = specs
    names = [*wrist, *spec.actuated_joints]
    return JointMap.named_after(spec, names, names)
