"""`spec.yaml`: how lerobot-opfa reads a hand model (joint mapping, couplings, link semantics, poses, and
where the documented hand frame sits in a vendor's model).

The spec is checked twice: on its own when loaded (`HandSpec.load`) and against the model when a `HandModel`
is built (`check_joints`; the links the spec leaves out labelled from the kinematic tree, `hands.labels`;
`check_links`). Every error names the file and the field.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

from lerobot_opfa.hands.universal import FINGERS, UNIVERSAL_INDEX
from lerobot_opfa.yaml_files import YamlFileError, read_yaml

KINDS = ("hand", "gripper")
SIDES = ("right", "left")
MODEL_SUFFIXES = (".urdf", ".xml", ".mjcf")


class HandSpecError(ValueError):
    """A spec that cannot describe its model; the message names the file and the field."""

    def __init__(self, path: Path | str, field_name: str, message: str):
        super().__init__(f"{path}: field '{field_name}': {message}")
        self.path = Path(path)
        self.field = field_name


@dataclass(frozen=True)
class Coupling:
    """q[joint] = scale * q[source] + offset (a mimic joint, tendon or linkage made linear)."""

    joint: str
    source: str
    scale: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class BaseFrame:
    """The documented hand frame in the model: `xyz` / `rpy` (URDF convention, radians) relative to `link`'s
    frame (the model's root frame when None), so a vendor file is used as it ships."""

    link: str | None = None
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class HandSpec:
    path: Path
    name: str
    kind: str
    model_path: Path
    description: str
    joints: dict[str, str]
    """Actuated model joint -> universal joint name, in the order of the hand's joint vector."""
    couplings: dict[str, Coupling]
    """Coupled model joint -> its coupling, in an order where every source comes first."""
    links: dict[str, tuple[int, int]]
    """Model link -> semantic label (finger u, segment v): the spec's own table, which overrides the labels
    the kinematic tree gives (`hands.labels`); a `HandModel`'s spec holds every link with geometry."""
    poses: dict[str, dict[str, float]] = field(default_factory=dict)
    signs: dict[str, float] = field(default_factory=dict)
    """Actuated joint -> -1 where the vendor's sense is the opposite of the universal table's."""
    fixed: dict[str, float] = field(default_factory=dict)
    """Movable model joints that are not the hand's (wrist, forearm), held at a value."""
    ignored_links: tuple[str, ...] = ()
    """Links labelled `null`: their geometry is simulated but is not the hand (a forearm), so no cloud."""
    base: BaseFrame = field(default_factory=BaseFrame)
    finger_roots: dict[int, str] = field(default_factory=dict)
    """Finger u -> its first model joint or link, where the kinematic tree cannot tell (a gripper's jaws)."""
    side: str = "right"
    """Which hand the model is; `hands check` compares it with the side the thumb is on."""
    root: str | None = None
    """The model's link (URDF) or body (MJCF) the hand hangs from, where the file holds more than the hand
    (an arm, a second hand): only the subtree below it is loaded, its frame the model's root frame."""

    @property
    def actuated_joints(self) -> list[str]:
        return list(self.joints)

    @property
    def universal_names(self) -> list[str]:
        """The universal joint of each actuated joint, in joint-vector order."""
        return [self.joints[j] for j in self.actuated_joints]

    @property
    def fingers(self) -> list[str]:
        """Names of the fingers (and palm) that this hand's links carry."""
        return [FINGERS[u] for u in sorted({u for u, _ in self.links.values()})]

    @cached_property
    def sha256(self) -> str:
        """Hash of what a GaLR checkpoint trained on this hand depends on: the model file and the spec's
        content except its expert poses and description (retuning a grasp pose keeps checkpoints valid)."""
        raw = read_yaml(self.path, "hand spec")
        relevant = {k: v for k, v in raw.items() if k not in ("poses", "description")}
        digest = hashlib.sha256(json.dumps(relevant, sort_keys=True).encode())
        digest.update(self.model_path.read_bytes())
        return digest.hexdigest()

    @classmethod
    def load(cls, path: str | Path) -> HandSpec:
        path = Path(path).resolve()
        if not path.is_file():
            raise HandSpecError(path, "<file>", "spec file not found")
        try:
            raw = read_yaml(path, "hand spec")
        except YamlFileError as err:
            raise HandSpecError(path, "<file>", str(err).split(": ", 1)[1]) from None
        if not isinstance(raw, dict):
            raise HandSpecError(path, "<file>", "expected a mapping at the top level")
        unknown = sorted(set(raw) - set(FIELDS))
        if unknown:
            raise HandSpecError(path, unknown[0], f"unknown field(s) {unknown}")

        name = _required(raw, "name", str, path)
        if not re.fullmatch(r"[a-z0-9_]+", name):
            raise HandSpecError(path, "name", f"'{name}' must match [a-z0-9_]+")
        kind = raw.get("kind", "hand")
        if kind not in KINDS:
            raise HandSpecError(path, "kind", f"'{kind}' is not one of {list(KINDS)}")
        side = raw.get("side", "right")
        if side not in SIDES:
            raise HandSpecError(path, "side", f"'{side}' is not one of {list(SIDES)}")
        model_path = (path.parent / _required(raw, "model", str, path)).resolve()
        if model_path.suffix.lower() not in MODEL_SUFFIXES:
            raise HandSpecError(path, "model", f"'{model_path.name}' is neither URDF (.urdf) nor MJCF (.xml)")
        if not model_path.is_file():
            raise HandSpecError(path, "model", f"model file '{model_path}' not found")

        joints, signs = _parse_joints(_mapping(raw, "joints", path), path)
        for joint, universal in joints.items():
            if universal not in UNIVERSAL_INDEX:
                raise HandSpecError(
                    path,
                    f"joints.{joint}",
                    f"'{universal}' is not in the universal joint table (see `lerobot-opfa hands joints`)",
                )
        used = [u for u in joints.values()]
        duplicates = sorted({u for u in used if used.count(u) > 1})
        if duplicates:
            raise HandSpecError(path, "joints", f"universal name(s) {duplicates} used by more than one joint")

        couplings = _parse_couplings(_mapping(raw, "couplings", path), joints, path)
        fixed = _parse_fixed(_mapping(raw, "fixed", path), {*joints, *couplings}, path)
        links, ignored = _parse_links(_mapping(raw, "links", path), path)
        poses = _parse_poses(_mapping(raw, "poses", path), joints, path)
        base = _parse_base(_mapping(raw, "base", path), path)
        finger_roots = _parse_fingers(_mapping(raw, "fingers", path), path)
        description = str(raw.get("description", ""))
        root = raw.get("root")
        if root is not None and not isinstance(root, str):
            raise HandSpecError(path, "root", f"expected the name of the hand's root link, got {root!r}")
        return cls(
            path,
            name,
            kind,
            model_path,
            description,
            joints,
            couplings,
            links,
            poses,
            signs,
            fixed,
            ignored,
            base,
            finger_roots,
            side,
            root,
        )

    def check_joints(self, joint_names: list[str]) -> None:
        """Raise if the spec and the model's joints disagree: every movable joint must be actuated, coupled
        or held, and every joint the spec names must exist."""
        model_joints = set(joint_names)
        sources = {c.source for c in self.couplings.values()}
        described = set(self.joints) | set(self.couplings) | set(self.fixed) | sources
        for field_name, names in (
            ("joints", self.joints),
            ("couplings", self.couplings),
            ("fixed", self.fixed),
        ):
            unknown = sorted(set(names) - model_joints)
            if unknown:
                raise HandSpecError(
                    self.path,
                    field_name,
                    f"unknown joint(s) {unknown}; the model's movable joints are {joint_names}",
                )
        unknown_sources = sorted({c.source for c in self.couplings.values()} - model_joints)
        if unknown_sources:
            raise HandSpecError(self.path, "couplings", f"unknown source joint(s) {unknown_sources}")
        missing = [j for j in joint_names if j not in described]
        if missing:
            raise HandSpecError(
                self.path,
                "joints",
                f"model joint(s) {missing} are neither actuated ('joints'), coupled ('couplings') nor held "
                "('fixed': for a wrist or forearm joint)",
            )

    def check_links(self, link_names: list[str], geometry_links: set[str]) -> None:
        """Raise if a labelled link is not in the model or carries no geometry (the cloud keeps its minimum
        of points on each); a link with geometry and no label is the kinematic tree's to label."""
        unknown_links = sorted((set(self.links) | set(self.ignored_links)) - set(link_names))
        if unknown_links:
            raise HandSpecError(
                self.path, "links", f"unknown link(s) {unknown_links}; the model's links are {link_names}"
            )
        bare = sorted(set(self.links) - geometry_links)
        if bare:
            raise HandSpecError(
                self.path,
                "links",
                f"link(s) {bare} are labelled but carry no geometry in the model, so the cloud has no points "
                "on them; give them a visual or collision shape, or leave them out",
            )
        if self.base.link is not None and self.base.link not in link_names:
            raise HandSpecError(
                self.path, "base.link", f"unknown link '{self.base.link}'; the model's links are {link_names}"
            )


FIELDS = (
    *("name", "kind", "side", "model", "root", "description", "base"),
    *("joints", "couplings", "fixed", "fingers", "links", "poses"),
)


def _required(raw: dict, key: str, kind: type, path: Path):
    if key not in raw:
        raise HandSpecError(path, key, "missing")
    if not isinstance(raw[key], kind):
        raise HandSpecError(path, key, f"expected {kind.__name__}, got {type(raw[key]).__name__}")
    return raw[key]


def _mapping(raw: dict, key: str, path: Path) -> dict:
    value = raw.get(key) or {}
    if not isinstance(value, dict):
        raise HandSpecError(path, key, f"expected a mapping, got {type(value).__name__}")
    return value


def _parse_joints(raw: dict, path: Path) -> tuple[dict[str, str], dict[str, float]]:
    """`joint: universal_name` or `joint: {universal: NAME, sign: -1}` -> (joint -> name, joint -> -1)."""
    if not raw:
        raise HandSpecError(path, "joints", "a hand needs at least one actuated joint")
    joints, signs = {}, {}
    for joint, entry in raw.items():
        where = f"joints.{joint}"
        if isinstance(entry, dict):
            extra = sorted(set(entry) - {"universal", "sign"})
            if extra or "universal" not in entry:
                raise HandSpecError(path, where, "expected a universal name or {universal: NAME, sign: -1}")
            if entry.get("sign", 1) not in (1, -1):
                raise HandSpecError(path, where, f"sign must be 1 or -1, got {entry['sign']!r}")
            if entry.get("sign", 1) == -1:
                signs[str(joint)] = -1.0
            entry = entry["universal"]
        joints[str(joint)] = str(entry)
    return joints, signs


def _parse_fixed(raw: dict, described: set[str], path: Path) -> dict[str, float]:
    fixed = {}
    for joint, value in raw.items():
        if joint in described:
            raise HandSpecError(
                path, f"fixed.{joint}", "a joint cannot be both fixed and actuated or coupled"
            )
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise HandSpecError(path, f"fixed.{joint}", f"expected the value to hold it at, got {value!r}")
        fixed[str(joint)] = float(value)
    return fixed


def _parse_base(raw: dict, path: Path) -> BaseFrame:
    extra = sorted(set(raw) - {"link", "xyz", "rpy"})
    if extra:
        raise HandSpecError(path, "base", f"unknown key(s) {extra}; expected link, xyz, rpy")
    vectors = {}
    for key in ("xyz", "rpy"):
        value = raw.get(key, [0.0, 0.0, 0.0])
        ok = isinstance(value, list) and len(value) == 3
        if not ok or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in value):
            raise HandSpecError(path, f"base.{key}", f"expected three numbers, got {value!r}")
        vectors[key] = tuple(float(x) for x in value)
    link = raw.get("link")
    return BaseFrame(None if link is None else str(link), vectors["xyz"], vectors["rpy"])


def _parse_couplings(raw: dict, joints: dict[str, str], path: Path) -> dict[str, Coupling]:
    parsed: dict[str, Coupling] = {}
    for joint, entry in raw.items():
        where = f"couplings.{joint}"
        if joint in joints:
            raise HandSpecError(path, where, "a joint cannot be both actuated and coupled")
        if not isinstance(entry, dict) or "source" not in entry:
            raise HandSpecError(path, where, "expected {source: JOINT, scale: A, offset: B}")
        extra = sorted(set(entry) - {"source", "scale", "offset"})
        if extra:
            raise HandSpecError(path, where, f"unknown key(s) {extra}")
        try:
            parsed[joint] = Coupling(
                joint, str(entry["source"]), float(entry.get("scale", 1.0)), float(entry.get("offset", 0.0))
            )
        except (TypeError, ValueError) as err:
            raise HandSpecError(path, where, f"scale and offset must be numbers ({err})") from err
    # Order so that every source precedes the joints it drives; a leftover means a cycle.
    ordered: dict[str, Coupling] = {}
    pending = dict(parsed)
    while pending:
        ready = [j for j, c in pending.items() if c.source not in pending]
        if not ready:
            cycle = _find_cycle(pending)
            raise HandSpecError(path, "couplings", f"coupling cycle: {' -> '.join(cycle)}")
        for joint in ready:
            ordered[joint] = pending.pop(joint)
    return ordered


def _find_cycle(pending: dict[str, Coupling]) -> list[str]:
    joint = next(iter(pending))
    seen: list[str] = []
    while joint not in seen:
        seen.append(joint)
        joint = pending[joint].source
    return seen[seen.index(joint) :] + [joint]


def _parse_fingers(raw: dict, path: Path) -> dict[int, str]:
    """`finger: joint or link` -> {finger u: that name}; the model is checked for it by `hands.labels`."""
    roots: dict[int, str] = {}
    for finger, root in raw.items():
        where = f"fingers.{finger}"
        if finger not in FINGERS[1:]:
            raise HandSpecError(path, where, f"not a finger; expected one of {list(FINGERS[1:])}")
        if not isinstance(root, str):
            raise HandSpecError(path, where, f"expected the finger's first joint or link, got {root!r}")
        if root in roots.values():
            raise HandSpecError(path, where, f"'{root}' is already another finger's root")
        roots[FINGERS.index(finger)] = root
    return roots


def _parse_links(raw: dict, path: Path) -> tuple[dict[str, tuple[int, int]], tuple[str, ...]]:
    links, ignored = {}, []
    for link, label in raw.items():
        if label is None:
            ignored.append(str(link))
            continue
        ok = isinstance(label, list) and len(label) == 2 and all(isinstance(x, int) for x in label)
        if not ok or not 0 <= label[0] < len(FINGERS) or label[1] < 0:
            raise HandSpecError(path, f"links.{link}", f"expected [finger 0-5, segment >= 0], got {label!r}")
        links[str(link)] = (label[0], label[1])
    return links, tuple(ignored)


def _parse_poses(raw: dict, joints: dict[str, str], path: Path) -> dict[str, dict[str, float]]:
    poses = {}
    for pose in ("open", "grasp"):
        if pose not in raw:
            raise HandSpecError(
                path, "poses", f"pose '{pose}' missing (scripted experts need open and grasp)"
            )
    for pose, values in raw.items():
        if not isinstance(values, dict):
            raise HandSpecError(path, f"poses.{pose}", "expected a mapping joint -> value")
        unknown = sorted(set(values) - set(joints))
        if unknown:
            raise HandSpecError(path, f"poses.{pose}", f"unknown actuated joint(s) {unknown}")
        poses[str(pose)] = {str(j): float(v) for j, v in values.items()}
    return poses
