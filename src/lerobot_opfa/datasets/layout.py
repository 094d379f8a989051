"""What a LeRobotDataset's state/action columns mean for lerobot-opfa.

Two layouts are understood, both read from `meta/info.json` feature names:
- native: one hand; `observation.state` / `action` = wrist entries, then that hand's actuated joints
  (names from its spec, any order);
- merged (written by `lerobot-opfa dataset merge`): wrist entries, the universal joints, optionally the
  cached GaLR latents `z0..`; `observation.embodiment` names the hands its ids index.

A dataset of a user's hand records its spec (path and hash) in `meta/opfa.json`, so every later command finds
the hand from the dataset alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa.datasets.io import read_json
from lerobot_opfa.features import OBS_EMBODIMENT
from lerobot_opfa.hands.registry import builtin_hands, hand_ref, load_spec
from lerobot_opfa.hands.spec import HandSpec
from lerobot_opfa.hands.universal import UNIVERSAL_JOINT_NAMES

LATENT_PREFIX = "z"
OPFA_META_FILE = "meta/opfa.json"
"""What lerobot-opfa records about a dataset: `hands` (user hands' specs: name -> {spec, sha256}); for a
merged dataset also its inputs and, with cached latents, the GaLR that computed them (`galr`, as given to
the merge, and `galr_fingerprint`)."""


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
    joint_names: list[str] = field(default_factory=list)
    """native: the hand's joint names in the dataset's column order."""
    latent_dim: int = 0
    """merged: width of the cached latents (0: none cached)."""
    galr_fingerprint: str | None = None


def feature_names(features: dict, key: str) -> list[str]:
    names = features[key].get("names")
    if isinstance(names, dict):  # {"motors": [...]} style
        names = next(iter(names.values()))
    if not names:
        raise ValueError(f"feature '{key}' has no names in meta/info.json; lerobot-opfa maps joints by name")
    return [str(n) for n in names]


def latent_names(latent_dim: int) -> list[str]:
    return [f"{LATENT_PREFIX}{i}" for i in range(latent_dim)]


def _hand_candidates(hands: list[str] | None) -> list[str]:
    """Hand names or spec paths to match against (default: the built-in hands)."""
    return list(hands) if hands else list(builtin_hands())


def identify_hand(names: list[str], robot_type: str | None, hands: list[str] | None = None) -> HandSpec:
    """The hand whose actuated joints a native state vector holds: `robot_type` when it names a hand,
    else the one candidate whose joints all appear. Errors list the missing and unknown names."""
    specs = list({s.path: s for s in map(load_spec, _hand_candidates(hands))}.values())
    named = [s for s in specs if s.name == robot_type]
    if named:
        spec = named[0]
        missing = [j for j in spec.actuated_joints if j not in names]
        if missing:
            extra = [n for n in names if n not in spec.actuated_joints]
            raise JointNameError(
                f"dataset joint names do not match hand '{spec.name}' ({spec.path}): missing {missing}; "
                f"unknown (not joints of '{spec.name}', would be read as wrist entries) {extra}"
            )
        return spec
    matches = [s for s in specs if set(s.actuated_joints) <= set(names)]
    if len(matches) == 1:
        return matches[0]
    if len(matches) > 1:
        best = max(len(s.actuated_joints) for s in matches)
        widest = [s for s in matches if len(s.actuated_joints) == best]
        if len(widest) == 1:
            return widest[0]
        raise JointNameError(
            f"joint names {names} fit several hands ({', '.join(s.name for s in widest)}); set the dataset's "
            "robot_type to the hand's name"
        )
    closest = max(specs, key=lambda s: len(set(s.actuated_joints) & set(names)))
    missing = [j for j in closest.actuated_joints if j not in names]
    unknown = [n for n in names if n not in closest.actuated_joints]
    raise JointNameError(
        f"no registered hand ({', '.join(s.name for s in specs)}) has all of the joints {names}. Closest: "
        f"'{closest.name}' ({closest.path}): missing {missing}; unknown {unknown}. Name the state/action "
        "entries after the spec's actuated joints (see `lerobot-opfa hands list`)"
    )


def split_native_names(names: list[str], spec: HandSpec) -> tuple[list[str], list[str]]:
    """(wrist names, joint names in column order): the hand's joints must form the trailing block."""
    joints = set(spec.actuated_joints)
    n_wrist = len(names) - len(joints)
    wrist, hand = names[:n_wrist], names[n_wrist:]
    if set(hand) != joints or any(n in joints for n in wrist):
        raise JointNameError(
            f"the joints of hand '{spec.name}' must follow the wrist entries: got {names}; missing "
            f"{[j for j in spec.actuated_joints if j not in names]}, unknown "
            f"{[n for n in hand if n not in joints]}"
        )
    return wrist, hand


def opfa_record(root: Path | str | None) -> dict:
    """What lerobot-opfa recorded about a dataset (empty for a dataset it did not write)."""
    meta = Path(root) / OPFA_META_FILE if root is not None else None
    return read_json(meta) if meta is not None and meta.is_file() else {}


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
    features: dict, robot_type: str | None = None, root: Path | str | None = None, hands=None
) -> DatasetLayout:
    """The layout of a dataset from its features and what `meta/opfa.json` under `root` records. `hands`:
    the hands (names or spec paths) it may hold besides the built-ins and the ones it records."""
    record = opfa_record(root)
    # The hands the dataset records come first: a user's hand named like a built-in is the user's.
    candidates = [*recorded_hands(root, record).values(), *_hand_candidates(hands)]
    names = feature_names(features, OBS_STATE)
    if ACTION in features and feature_names(features, ACTION) != names:
        raise JointNameError(
            f"'{ACTION}' and '{OBS_STATE}' must name the same entries in the same order; got "
            f"{feature_names(features, ACTION)} and {names}"
        )
    if OBS_EMBODIMENT in features:
        embodiments = feature_names(features, OBS_EMBODIMENT)
        universal = list(UNIVERSAL_JOINT_NAMES)
        starts = [i for i in range(len(names)) if names[i : i + len(universal)] == universal]
        if not starts:
            raise JointNameError(f"a merged dataset's state must hold the universal joints {universal}")
        wrist, rest = names[: starts[0]], names[starts[0] + len(universal) :]
        if rest and rest != latent_names(len(rest)):
            raise JointNameError(f"unexpected entries after the universal joints: {rest}")
        specs = {}
        for spec in map(load_spec, candidates):
            specs.setdefault(spec.name, spec)
        unknown = [h for h in embodiments if h not in specs]
        if unknown:
            raise ValueError(
                f"{root}: hand(s) {unknown} are neither built in nor recorded by the dataset (meta/opfa.json)"
            )
        refs = [hand_ref(specs[h]) for h in embodiments]
        fingerprint = record.get("galr_fingerprint")
        return DatasetLayout("merged", embodiments, refs, wrist, [], len(rest), fingerprint)
    spec = identify_hand(names, robot_type, candidates)
    wrist, joints = split_native_names(names, spec)
    return DatasetLayout("native", [spec.name], [hand_ref(spec)], wrist, joints)
