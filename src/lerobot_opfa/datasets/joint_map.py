"""Joint maps: which entries of a robot's `observation.state` / `action` are which joint of a hand, in which
units. The one place where a robot's vectors meet the policy's: the processors split observations with it
on the way in and join actions with it on the way out, and save it, so a deployed policy speaks the robot's
entries (LeRobot's `lerobot-rollout` hands the action to the robot by position).

A map is a small YAML file (docs/usage.md):

    hand: leap                      # a built-in name, or a spec.yaml path relative to this file
    joints:                         # dataset entry: the spec joint it is (same units) ...
      right_hand.ring_mcp_side.pos: ring_mcp_abd
      right_hand.ring_mcp_fwd.pos: {joint: ring_mcp_flex, scale: 0.0174533, offset: 0.0}  # ... or in degrees
    drop: [right_hand.ring_current]  # observation-only entries the policy does not read (optional)
    robot_type: so101_ability       # only to confirm a dataset whose robot_type names another hand (optional)

A spec joint's value is `scale * entry + offset`. Every other entry is body state (an arm's joints, a wrist
pose in any convention) that the policy models as it is. A robot whose state and action hold the hand
under different entries (a gripper reading in -1..1, a grasp command in 0..1) gives them apart, each key
naming every joint once (`joints` is shared by both):

    state_joints: {gripper: {joint: left_jaw_joint, scale: -0.022, offset: 0.022}}  # umi's jaw, metres
    action_joints: {grasp: {joint: left_jaw_joint, scale: -0.044, offset: 0.044}}

Its state's body entries and its action's are then what is left of each: they may differ (arm joints in
the state, end-effector deltas in the action). A dataset whose hand entries are named after the spec's
joints (or `<joint>.pos`) needs no file (`JointMap.named_after`).

A robot with two hands (a G1 with Dex3 or Inspire hands, a two-arm rig) lists one slot per hand, each with
its side, its hand and its entries (`joints`, `state_joints`, `action_joints` as above); `drop` and
`robot_type` stay at the top. A left hand is read through the right-hand model of the same hand: the joint
values mean the same on both sides (a flexion is a flexion), only the geometry is mirrored.

    slots:
      - side: left
        hand: inspire
        joints: {kLeftHandIndex: {joint: index_mcp_flex, scale: -1.47, offset: 1.47}, ...}
      - side: right
        hand: inspire
        joints: {kRightHandIndex: {joint: index_mcp_flex, scale: -1.47, offset: 1.47}, ...}

A hand on an arm the package models (`arm: ur5`, a built-in or an arm spec path; in a slot, or at the top of
a one-handed map) has its arm's joint entries read as the tool pose in the workspace (`arms.pose`: FK on
the way in, IK seeded at the joints the arm holds on the way out): the body convention robots of different
arms share. The arm's entries are named after its joints (`shoulder_pan_joint`, `<joint>.pos`, or with the
slot's side, `left_<joint>.pos`) or listed in `arm_joints` (entry: arm joint, or `{joint, scale, offset}`
for degrees). An armed robot's body is its arms: every other entry is a hand's, or dropped. Two bodies are
poses already and need no arm model: `arm: floating`, the simulator's floating wrist (`wrist_x, wrist_y,
wrist_z, wrist_yaw, wrist_pitch, wrist_roll`), and `arm: end_effector`, LeRobot's end-effector entries
(`ee.x, ee.y, ee.z, ee.wx, ee.wy, ee.wz`, a rotation vector).
"""

from __future__ import annotations

import difflib
import logging
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa.hands.model import LIMIT_TOLERANCE
from lerobot_opfa.hands.registry import builtin_hands, hand_ref, load_spec
from lerobot_opfa.hands.spec import HandSpec
from lerobot_opfa.yaml_files import YamlFileError, read_yaml

logger = logging.getLogger(__name__)

SPAN_FRACTION = 0.1
"""A scaled joint whose frames use less than this fraction of its range, while its entries as recorded
span more within its limits, is a scale applied to entries already in the spec's units (`check_spans`)."""
AGAINST_STATE = -0.5
"""A joint whose commanded value and the state it reaches a frame later correlate below this is read the
wrong way round in one of the two (`check_senses`): a recorded robot's correlate at about +0.96."""

POSITION_SUFFIX = ".pos"
"""LeRobot's robots name a motor's position entry `<motor>.pos` (what `lerobot-record` writes)."""


def joint_of(entry: str) -> str:
    """The joint an entry named after it stands for: itself, or `<joint>.pos`."""
    return entry.removesuffix(POSITION_SUFFIX)


HANDS_SEPARATOR = "+"
"""A two-armed robot named by its hands, left first: `inspire+xhand` (its `robot_type` as the simulated rig
records it, and how a policy's pipeline names it)."""


def sided(side: str, name: str) -> str:
    """An entry of one side of a two-armed robot, as LeRobot's bimanual robots name them: `left_<name>`."""
    return f"{side}_{name}"


def arm_entries(arms: dict[str, HandSpec], body: list[str]) -> list[str]:
    """A two-armed robot's entries as the simulator lays them out: per side, its `body` entries, then its
    hand's joints in spec order, each `<side>_<name>`."""
    return [sided(side, name) for side, spec in arms.items() for name in (*body, *spec.actuated_joints)]


Columns = tuple[list[int], torch.Tensor, torch.Tensor]
"""A slot's columns of a robot's vector, with the scale and offset that turn each into its joint's units."""


class JointMapError(ValueError):
    """A joint map that does not fit its dataset or its hand; the message names the map and the entry."""


@dataclass(frozen=True)
class MappedJoint:
    joint: str
    """The spec's (model) joint name."""
    scale: float = 1.0
    offset: float = 0.0


SIDES = ("left", "right")
SLOT_FIELDS = ("side", "hand", "joints", "state_joints", "action_joints", "arm", "arm_joints")
TOOL_POSE = "tool"
"""An armed robot's body entries in the policy's space: `tool.<POSE_NAMES>` (`left.tool.x` with sides)."""
DEGREE = math.pi / 180


@dataclass(frozen=True)
class HandSlot:
    """One hand of a robot: which hand, on which side, under which entries."""

    hand: str
    """What `load_hand` takes: a built-in name or a spec path."""
    joints: dict[str, MappedJoint]
    """Entry of both the state and the action -> the spec joint it holds."""
    state_joints: dict[str, MappedJoint] = field(default_factory=dict)
    action_joints: dict[str, MappedJoint] = field(default_factory=dict)
    """Entries of only the state, or only the action -> the spec joint each holds (`key_joints`)."""
    side: str | None = None
    """`left` or `right` (None: a one-handed robot's, the side unsaid)."""
    arm: str | None = None
    """The arm the hand is mounted on (what `arms.spec.load_arm` takes); None: the body entries are the
    policy's as they are."""
    arm_joints: dict[str, MappedJoint] = field(default_factory=dict)
    """Entry of both the state and the action -> the arm joint it holds (bound: every joint of the arm)."""

    def key_joints(self, key: str) -> dict[str, MappedJoint]:
        """`key`'s entries ("observation.state" or "action") that hold this hand's joints."""
        return {**self.joints, **(self.state_joints if key == OBS_STATE else self.action_joints)}

    @property
    def spec(self) -> HandSpec:
        return load_spec(self.hand)

    @classmethod
    def from_dict(cls, raw: dict, source: str) -> HandSlot:
        tables = ("joints", "state_joints", "action_joints", "arm_joints")
        if not any(raw.get(t) for t in tables[:3]):
            raise JointMapError(
                f"{source}: needs a mapping 'joints' of dataset entry -> spec joint (or, where the state "
                "and the action hold the hand under different entries, 'state_joints' and 'action_joints')"
            )
        if not isinstance(raw.get("hand"), str):
            raise JointMapError(f"{source}: needs 'hand', a built-in hand's name or a spec.yaml path")
        arm = raw.get("arm")
        if arm is not None and not isinstance(arm, str):
            raise JointMapError(f"{source}: 'arm' must be a built-in arm's name or an arm spec path")
        if raw.get("arm_joints") and arm is None:
            raise JointMapError(f"{source}: 'arm_joints' needs 'arm', the arm they are the joints of")
        side = raw.get("side")
        if side is not None and side not in SIDES:
            raise JointMapError(f"{source}: 'side' must be one of {list(SIDES)}, got {side!r}")
        for table in tables:
            if not isinstance(raw.get(table) or {}, dict):
                raise JointMapError(f"{source}: '{table}' must be a mapping of dataset entry -> spec joint")
        joints = {
            table: {
                str(entry): _mapped_joint(value, f"{source}: {table} entry '{entry}'")
                for entry, value in (raw.get(table) or {}).items()
            }
            for table in tables
        }
        return cls(
            raw["hand"], joints["joints"], joints["state_joints"], joints["action_joints"], side, arm,
            joints["arm_joints"],
        )  # fmt: skip

    def to_dict(self) -> dict:
        def table(joints: dict[str, MappedJoint]) -> dict:
            return {e: {"joint": j.joint, "scale": j.scale, "offset": j.offset} for e, j in joints.items()}

        apart = {
            name: table(joints)
            for name, joints in (("state_joints", self.state_joints), ("action_joints", self.action_joints))
            if joints
        }
        side = {} if self.side is None else {"side": self.side}
        arm = {} if self.arm is None else {"arm": self.arm, "arm_joints": table(self.arm_joints)}
        return {**side, "hand": self.hand, "joints": table(self.joints), **apart, **arm}


@dataclass(frozen=True)
class JointMap:
    slots: tuple[HandSlot, ...]
    """The robot's hands, one per slot, in the order the policy holds them."""
    drop: tuple[str, ...] = ()
    robot_type: str | None = None
    """The dataset `robot_type` the map is confirmed for when it names another hand (`check_robot_type`)."""
    source: str = "joint map"
    """Where the map came from, for messages."""
    state_names: tuple[str, ...] = ()
    action_names: tuple[str, ...] = ()
    """The robot's entries the map is bound to (`bind`); empty for a map as read from its file."""
    _columns: dict = field(default_factory=dict, compare=False, repr=False)
    _arms: dict = field(default_factory=dict, compare=False, repr=False)
    """(arm reference, hand reference) -> its body (`arms.pose.load_body`), loaded on first use."""

    # --- reading and writing ----------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> JointMap:
        path = Path(path)
        try:
            raw = read_yaml(path, "joint map")
        except YamlFileError as err:
            raise JointMapError(str(err)) from None
        slots = raw.get("slots") if isinstance(raw, dict) else None
        for slot in slots if isinstance(slots, list) else [raw]:
            hand = slot.get("hand") if isinstance(slot, dict) else None
            if isinstance(hand, str) and hand not in builtin_hands() and not Path(hand).is_absolute():
                slot["hand"] = str((path.parent / hand).resolve())
            arm = slot.get("arm") if isinstance(slot, dict) else None
            if isinstance(arm, str) and arm.endswith((".yaml", ".yml")) and not Path(arm).is_absolute():
                slot["arm"] = str((path.parent / arm).resolve())
        return cls.from_dict(raw, str(path))

    @classmethod
    def from_dict(cls, raw, source: str = "joint map") -> JointMap:
        if not isinstance(raw, dict):
            raise JointMapError(f"{source}: must be a mapping with 'hand' and 'joints' (or 'slots')")
        top = {"drop", "robot_type", "state_names", "action_names"}
        if "slots" in raw:
            slots = raw["slots"]
            if not isinstance(slots, list) or not slots or not all(isinstance(s, dict) for s in slots):
                raise JointMapError(
                    f"{source}: 'slots' must be a list of hands, each with side, hand, joints"
                )
            for index, slot in enumerate(slots):
                unknown = set(slot) - set(SLOT_FIELDS)
                if unknown:
                    raise JointMapError(
                        f"{source}: slot {index}: unknown field(s) {sorted(unknown)} "
                        f"({', '.join(SLOT_FIELDS)})"
                    )
            parsed = tuple(HandSlot.from_dict(s, f"{source}: slot {i}") for i, s in enumerate(slots))
            sides = [s.side for s in parsed]
            if len(parsed) > 1 and (None in sides or len(set(sides)) < len(sides)):
                raise JointMapError(
                    f"{source}: each slot of a two-handed robot names its side, once: {sides}"
                )
            allowed = top | {"slots"}
        else:
            parsed = (HandSlot.from_dict(raw, source),)
            allowed = top | set(SLOT_FIELDS) - {"side"}
        unknown = set(raw) - allowed
        if unknown and "slots" in raw and unknown <= set(SLOT_FIELDS):
            raise JointMapError(
                f"{source}: {', '.join(sorted(unknown))} beside `slots`: a map with slots gives each hand's "
                "fields in its slot (`- side: left` then `hand:`, `joints:`); a one-handed robot's map has "
                "no `slots`"
            )
        if unknown:
            raise JointMapError(
                f"{source}: unknown field(s) {sorted(unknown)} (valid here: {', '.join(sorted(allowed))})"
            )
        drop = raw.get("drop") or []
        if not isinstance(drop, list):
            raise JointMapError(f"{source}: 'drop' must be a list of entry names")
        robot_type = raw.get("robot_type")
        if robot_type is not None and not isinstance(robot_type, str):
            raise JointMapError(f"{source}: 'robot_type' must be a dataset's robot_type, got {robot_type!r}")
        return cls(
            slots=parsed,
            drop=tuple(map(str, drop)),
            robot_type=robot_type,
            source=source,
            state_names=tuple(raw.get("state_names", ())),
            action_names=tuple(raw.get("action_names", ())),
        )

    def to_dict(self) -> dict:
        """What a checkpoint or a merged dataset saves (with the names it is bound to); a one-handed robot's
        map in the one-hand form."""
        one = len(self.slots) == 1 and self.slots[0].side is None
        hands = self.slots[0].to_dict() if one else {"slots": [s.to_dict() for s in self.slots]}
        return {
            **hands,
            "drop": list(self.drop),
            **({"robot_type": self.robot_type} if self.robot_type is not None else {}),
            "state_names": list(self.state_names),
            "action_names": list(self.action_names),
        }

    @classmethod
    def named_after(
        cls, spec: HandSpec, state_names: list[str], action_names: list[str], arm: str | None = None
    ) -> JointMap:
        """The map of a robot whose hand entries carry the spec's joint names (or LeRobot's `<joint>.pos`),
        in the spec's units; its body entries those of `arm`, where given."""
        entries = {**{joint_of(n): n for n in action_names}, **{n: n for n in action_names}}
        joints = {entries.get(j, j): MappedJoint(j) for j in spec.actuated_joints}
        slot = HandSlot(hand_ref(spec), joints, arm=arm)
        return cls((slot,), source=f"hand '{spec.name}'").bind(state_names, action_names)

    @classmethod
    def named_after_arms(
        cls,
        arms: dict[str, HandSpec],
        state_names: list[str],
        action_names: list[str],
        arm: str | None = None,
    ) -> JointMap:
        """The map of a two-armed robot whose hand entries are named `<side>_<joint>` (or, as LeRobot's
        robots record them, `<side>_<joint>.pos`), in the specs' units: the two-armed simulator's; each
        side's body entries those of `arm`, where given."""

        def entry(side: str, joint: str) -> str:
            name = sided(side, joint)
            return name if name in action_names else f"{name}{POSITION_SUFFIX}"

        slots = tuple(
            HandSlot(
                hand_ref(spec),
                {entry(side, j): MappedJoint(j) for j in spec.actuated_joints},
                side=side,
                arm=arm,
            )
            for side, spec in arms.items()
        )
        source = f"hands {HANDS_SEPARATOR.join(spec.name for spec in arms.values())}"
        return cls(slots, source=source).bind(state_names, action_names)

    def with_hand(self, old: str, new: str) -> JointMap:
        """This map with the slots of hand reference `old` pointing at `new` (a user hand unpacked
        elsewhere)."""
        slots = tuple(replace(s, hand=new) if s.hand == old else s for s in self.slots)
        return replace(self, slots=slots, _columns={})

    # --- binding to a robot's entries -----------------------------------------------------------------
    def bind(self, state_names: list[str], action_names: list[str]) -> JointMap:
        """This map checked against a robot's (a dataset's) state and action entries and the hands' specs."""
        state, action = list(map(str, state_names)), list(map(str, action_names))
        for slot in self.slots:
            self._bind_slot(slot, state, action)
        slots = tuple(replace(s, arm_joints=self._arm_entries(s, state, action)) for s in self.slots)
        for key in (OBS_STATE, ACTION):
            claimed = [e for slot in self.slots for e in slot.key_joints(key)]
            twice = sorted({e for e in claimed if claimed.count(e) > 1})
            if twice:
                raise JointMapError(f"{self.source}: entries {twice} are given to two hand slots in {key}")
        for slot in self.slots:
            entries = [e for key in (OBS_STATE, ACTION) for e in slot.key_joints(key)]
            other = next((e for e in entries if slot.side and entry_side(e) not in (None, slot.side)), None)
            if other is not None:
                raise JointMapError(
                    f"{self.source} ({slot.side} hand): entry {other!r} names the {entry_side(other)} side, "
                    f"but the slot is the {slot.side} hand's; swap the slots' `side` (or their entries)"
                )
        for entry in self.drop:
            if entry in self.key_joints(OBS_STATE) or entry in action:
                raise JointMapError(
                    f"{self.source}: drop lists '{entry}', which is "
                    + (
                        "a joint of the map"
                        if entry in self.key_joints(OBS_STATE)
                        else "an action entry (the robot needs it)"
                    )
                )
            if entry not in state:
                raise JointMapError(f"{self.source}: drop lists '{entry}', which is not in observation.state")
        bound = replace(self, slots=slots, state_names=tuple(state), action_names=tuple(action), _columns={})
        bound._check_arm_body()
        return bound

    def _arm_entries(self, slot: HandSlot, state: list[str], action: list[str]) -> dict[str, MappedJoint]:
        """The slot's arm entries: as the map gives them, or the entries named after the arm's joints
        (`<joint>`, `<joint>.pos`, with the slot's side `<side>_<joint>[.pos]`), each in the state and the
        action."""
        if slot.arm is None:
            return {}
        where = f"{self.source}" + (f" ({slot.side} arm)" if slot.side else "")
        joints = self.arm(slot).joint_names
        given = dict(slot.arm_joints)
        if not given:
            for joint in joints:
                names = [joint, f"{joint}{POSITION_SUFFIX}"]
                names += [sided(slot.side, n) for n in names] if slot.side else []
                found = [n for n in names if n in state and n in action]
                if not found:
                    raise JointMapError(
                        f"{where}: arm '{slot.arm}' joint '{joint}' has no entry in both the state and the "
                        f"action ({' or '.join(names)}); name the arm's entries in `arm_joints`"
                    )
                given[found[0]] = MappedJoint(joint)
        held = [j.joint for j in given.values()]
        if sorted(held) != sorted(joints):
            raise JointMapError(
                f"{where}: `arm_joints` must name each joint of arm '{slot.arm}' once ({', '.join(joints)}), "
                f"got {held}"
            )
        absent = [e for e in given if e not in state or e not in action]
        if absent:
            raise JointMapError(
                f"{where}: arm entry {absent[0]!r} is not in both the state and the action (an arm's joints "
                "are read in both)"
            )
        return given

    def _check_arm_body(self) -> None:
        """An armed robot's body is its hands' tool poses: each slot names an arm, and every entry is an
        arm's or a hand's joint or dropped (another entry would have nowhere to go in the policy's space)."""
        armed = [slot.arm is not None for slot in self.slots]
        if not any(armed):
            return
        if not all(armed):
            raise JointMapError(f"{self.source}: give every hand slot its `arm`, or none")
        for key in (OBS_STATE, ACTION):
            free = self._free_body(key)
            if free:
                fix = "drop them (`drop:`)" if key == OBS_STATE else "an action entry must be a joint"
                raise JointMapError(
                    f"{self.source}: {key} entries {free[:4]} are neither an arm's nor a hand's joint; an "
                    f"armed robot's body is its hand's tool pose: {fix}"
                )

    @property
    def armed(self) -> bool:
        """Whether the body entries are arm joints (or another body), read as the hands' tool poses."""
        return self.slots[0].arm is not None

    def arm(self, slot: HandSlot):
        """The body of `slot`'s arm (`arms.pose.load_body`: an arm, or a pose body such as the simulator's
        floating wrist), loaded once per map."""
        from lerobot_opfa.arms.pose import POSE_BODIES, load_body  # pytorch-kinematics only for arms

        key = (slot.arm, slot.hand)
        if key not in self._arms:
            try:
                self._arms[key] = load_body(slot.arm, slot.hand)
            except ValueError as err:
                poses = ", ".join(POSE_BODIES)
                raise JointMapError(
                    f"{self.source}: arm '{slot.arm}': {err} (or a pose body: {poses})"
                ) from None
        return self._arms[key]

    def _bind_slot(self, slot: HandSlot, state: list[str], action: list[str]) -> None:
        spec = slot.spec
        where = self.source + (f" ({slot.side} hand)" if slot.side else "")
        for key, names in ((OBS_STATE, state), (ACTION, action)):
            for entry in slot.key_joints(key):
                if entry not in names:
                    near = difflib.get_close_matches(entry, names, n=3)
                    raise JointMapError(
                        f"{where}: entry {entry!r} is not in the dataset's {key}"
                        + (
                            f" (closest: {', '.join(map(repr, near))})"
                            if near
                            else f" ({len(names)} entries: {names[:8]} ...)"
                        )
                        + (
                            "; an entry of only the state or only the action goes under 'state_joints' or "
                            "'action_joints'"
                            if entry in slot.joints
                            else ""
                        )
                    )
            held = [j.joint for j in slot.key_joints(key).values()]
            unknown = [j for j in held if j not in spec.joints]
            twice = sorted({j for j in held if held.count(j) > 1})
            missing = [j for j in spec.actuated_joints if j not in held]
            if unknown or twice or missing:
                raise JointMapError(
                    f"{where}: must name each joint of hand '{spec.name}' once in {key} "
                    f"({', '.join(spec.actuated_joints)}): unknown {unknown}, twice {twice}, "
                    f"missing {missing}"
                )

    def key_joints(self, key: str) -> dict[str, MappedJoint]:
        """`key`'s entries ("observation.state" or "action") that hold a hand's joints, of every slot."""
        return {e: j for slot in self.slots for e, j in slot.key_joints(key).items()}

    def check_robot_type(self, robot_type: str | None) -> None:
        """Refuses a map for other hands than the one the dataset's `robot_type` names (`inspire`, or a word
        of `arm_inspire`), unless the map confirms that robot_type: the policy would learn the wrong hand
        without a word."""
        named, hands = hands_named_in(robot_type), [slot.spec.name for slot in self.slots]
        if not named or set(hands) & set(named) or self.robot_type == robot_type:
            return
        other, hand = max(named, key=len), hands[0]  # `inspire_tactile` rather than the `inspire` inside it
        raise JointMapError(
            f"{self.source}: maps hand '{hand}', but the dataset's robot_type '{robot_type}' names hand "
            f"'{other}'; use a map for '{other}', or, if this robot does carry '{hand}', confirm it with the "
            f"line `robot_type: {robot_type}` in the map"
        )

    def check_spans(self, x: torch.Tensor, key: str, limits: list[tuple[torch.Tensor, torch.Tensor]]) -> None:
        """Refuses a scale that squeezes a joint into less than `SPAN_FRACTION` of its range (`limits`: per
        slot, the hand's lower and upper limits in spec order) while its entry as recorded spans more, within
        those limits: a degrees scale on entries already in radians, which the limit check lets through. Any
        other scaled joint that moves over less than `SPAN_FRACTION` of its range is a warning naming it: a
        scale too small, or a joint the demos barely move."""
        names = self.names(key)
        x = x.detach().to("cpu", torch.float64).reshape(-1, x.shape[-1])
        if not len(x):
            return
        for slot, (lower, upper) in zip(self.slots, limits, strict=True):
            by_joint = {j.joint: (e, j) for e, j in slot.key_joints(key).items()}
            for i, joint in enumerate(slot.spec.actuated_joints):
                entry, mapped = by_joint[joint]
                raw, low, high = x[:, names.index(entry)], float(lower[i]), float(upper[i])
                width, recorded = high - low, float(raw.max() - raw.min())
                span = abs(mapped.scale) * recorded
                within = fits_limits((float(raw.min()), float(raw.max())), (low, high))
                if mapped.scale != 1 and span < SPAN_FRACTION * width <= recorded and within:
                    raise JointMapError(
                        f"{self.source}: entry {entry!r} with scale {mapped.scale:g} moves joint '{joint}' "
                        f"over {span:.3g} of its range {width:.3g} ([{low:.3g}, {high:.3g}]) in {key}, while "
                        f"as recorded it spans {recorded:.3g} within those limits: it is in the spec's units "
                        "already (radians, metres); use scale 1, or invert the scale if it is the wrong way "
                        "round"
                    )
                if mapped.scale != 1 and span < SPAN_FRACTION * width:
                    logger.warning(
                        "%s: entry %r with scale %g moves joint '%s' over %.3g of its range %.3g in %s "
                        "(under a tenth): check the scale, or that the demos move this joint",
                        self.source, entry, mapped.scale, joint, span, width, key,
                    )  # fmt: skip

    def check_senses(self, state: torch.Tensor, action: torch.Tensor, episodes: torch.Tensor) -> None:
        """Refuses a joint whose commands (`action`) and the states they lead to (`state` a frame later, in
        the same episode) run against each other: a scale of the wrong sign in `action_joints` or
        `state_joints` keeps every value inside the limits, and the policy would learn to open the hand
        where the demos closed it."""
        _, states = self.split(state.detach().to("cpu", torch.float64), OBS_STATE)
        _, actions = self.split(action.detach().to("cpu", torch.float64), ACTION)
        same = episodes[1:] == episodes[:-1]
        for slot, q_state, q_action in zip(self.slots, states, actions, strict=True):
            entries = {
                key: {j.joint: e for e, j in slot.key_joints(key).items()} for key in (OBS_STATE, ACTION)
            }
            for i, joint in enumerate(slot.spec.actuated_joints):
                reached, commanded = q_state[1:, i][same], q_action[:-1, i][same]
                if len(reached) < 3 or reached.std() < 1e-9 or commanded.std() < 1e-9:
                    continue
                r = float(torch.corrcoef(torch.stack([reached, commanded]))[0, 1])
                if r < AGAINST_STATE:
                    raise JointMapError(
                        f"{self.source}: joint '{joint}' runs against itself: the state it reaches "
                        f"({entries[OBS_STATE][joint]!r}) follows its command ({entries[ACTION][joint]!r}) "
                        f"with correlation {r:.2f}; one of the two entries' scale has the wrong sign "
                        "(flip it and its offset)"
                    )

    def body_names(self, key: str) -> list[str]:
        """The body entries of the policy's `key`: the robot's entries besides the hands' joints (and the
        dropped ones), in its order, which the policy models as they are; for an armed robot each arm's
        hand's tool pose (`tool.x`, ..., `left.tool.x` with sides)."""
        if not self.armed:
            return self._free_body(key)
        from lerobot_opfa.arms.pose import POSE_NAMES

        prefixes = [f"{slot.side}.{TOOL_POSE}" if slot.side else TOOL_POSE for slot in self.slots]
        return [f"{prefix}.{name}" for prefix in prefixes for name in POSE_NAMES]

    def _free_body(self, key: str) -> list[str]:
        joints = {**self.key_joints(key), **{e: j for slot in self.slots for e, j in slot.arm_joints.items()}}
        return [n for n in self.names(key) if n not in joints and n not in self.drop]

    def arm_joints(self, x: torch.Tensor, key: str) -> list[torch.Tensor]:
        """Per slot, its arm's joints (..., dof) in the arm's order and units, from a robot's `key` rows."""
        return [self._scaled(x, columns) for columns in self._indices(key)[2]]

    def check_arms(self, x: torch.Tensor, key: str, where: str) -> None:
        """Refuses arm joints outside the arm's limits, naming the entry (recorded in degrees where the
        spec's radians are declared: the scale that fits is named)."""
        arms = self.arm_joints(x.detach().to("cpu", torch.float64), key)
        for slot, q in zip(self.slots, arms, strict=True):
            arm = self.arm(slot)
            q = q.reshape(-1, q.shape[-1])
            for i, joint in enumerate(arm.joint_names):
                low, high = float(arm.lower[i]), float(arm.upper[i])
                recorded = (float(q[:, i].min()), float(q[:, i].max())) if len(q) else (low, high)
                if fits_limits(recorded, (low, high)):
                    continue
                entry = next(e for e, j in slot.arm_joints.items() if j.joint == joint)
                degrees = fits_limits(recorded, (low, high), DEGREE)
                hint = f"in degrees? give it `{{joint: {joint}, scale: {DEGREE:.7f}}}` in `arm_joints`"
                raise JointMapError(
                    f"{where}: arm entry {entry!r} ({joint}) spans [{recorded[0]:.3g}, {recorded[1]:.3g}], "
                    f"outside the limits [{low:.3g}, {high:.3g}] of arm '{slot.arm}'; "
                    + (hint if degrees else "check its unit and offset in `arm_joints`")
                )

    def entry_noise(self, key: str, body_noise: float, joint_noise: list[torch.Tensor]) -> torch.Tensor:
        """(entries,) physical noise of each of `key`'s entries in the robot's units: `body_noise` for a
        body entry, the slot's `joint_noise` (per joint in spec order, its units) over the entry's scale."""
        names, noise = self.names(key), torch.full((len(self.names(key)),), body_noise, dtype=torch.float64)
        for slot, per_joint in zip(self.slots, joint_noise, strict=True):
            order = slot.spec.actuated_joints
            for entry, mapped in slot.key_joints(key).items():
                noise[names.index(entry)] = float(per_joint[order.index(mapped.joint)]) / abs(mapped.scale)
        return noise

    def _indices(self, key: str) -> tuple[list[int], list[Columns], list[Columns]]:
        """(body columns, per slot: its hand's joint columns in spec order, scale, offset; per armed slot:
        its arm's, in the arm's joint order) of `key`'s vectors."""
        if key not in self._columns:
            if not self.action_names:
                raise JointMapError(f"{self.source}: not bound to a robot's entries (JointMap.bind)")
            names, slots = self.names(key), []
            for slot in self.slots:
                by_joint = {j.joint: (e, j) for e, j in slot.key_joints(key).items()}
                order = [by_joint[j] for j in slot.spec.actuated_joints]
                slots.append((
                    [names.index(e) for e, _ in order],
                    torch.tensor([j.scale for _, j in order], dtype=torch.float64),
                    torch.tensor([j.offset for _, j in order], dtype=torch.float64),
                ))  # fmt: skip
            arms = []
            for slot in self.slots if self.armed else ():
                by_joint = {j.joint: (e, j) for e, j in slot.arm_joints.items()}
                order = [by_joint[j] for j in self.arm(slot).joint_names]
                arms.append((
                    [names.index(e) for e, _ in order],
                    torch.tensor([j.scale for _, j in order], dtype=torch.float64),
                    torch.tensor([j.offset for _, j in order], dtype=torch.float64),
                ))  # fmt: skip
            self._columns[key] = ([names.index(n) for n in self._free_body(key)], slots, arms)
        return self._columns[key]

    def names(self, key: str) -> list[str]:
        """The robot's entries of `key` ("observation.state" or "action")."""
        return list(self.state_names if key == OBS_STATE else self.action_names)

    def split(self, x: torch.Tensor, key: str) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """(..., robot entries) of `key` ("observation.state" or "action") -> (body entries, per slot the
        hand's joints in spec order and units)."""
        names = self.names(key)
        if x.shape[-1] != len(names):
            raise ValueError(
                f"{key} has {x.shape[-1]} entries; the robot this policy was trained on has {len(names)} "
                f"({self.source}: {', '.join(names[:6])} ...)"
            )
        body, slots, _ = self._indices(key)
        qs = [self._scaled(x, columns) for columns in slots]
        if not self.armed:
            return x[..., body], qs
        poses = [
            self.arm(slot).pose(q.reshape(-1, q.shape[-1])).reshape(*q.shape[:-1], -1)
            for slot, q in zip(self.slots, self.arm_joints(x, key), strict=True)
        ]
        return torch.cat(poses, dim=-1).to(x.dtype), qs

    @staticmethod
    def _scaled(x: torch.Tensor, columns: Columns) -> torch.Tensor:
        index, scale, offset = columns
        return x[..., index] * scale.to(x.device, x.dtype) + offset.to(x.device, x.dtype)

    def reach(
        self, body: torch.Tensor, state: torch.Tensor | None = None, seconds: float | None = None
    ) -> tuple[list[torch.Tensor], int, int]:
        """An armed robot's tool poses (B, [T], 9 per slot) -> per slot its arm's joints (B, [T], dof) by IK
        seeded at the joints the arm holds in `state` (B, state entries; None: its home), every pose of the
        batch in one solve; how many poses were out of reach (answered with the nearest pose, never
        refused); and, given the `seconds` between actions, how many were held back to the arm's velocity
        limits (each action at most `speed * seconds` from the one before, the first from `state`)."""
        from lerobot_opfa.arms.ik import within_speed  # pytorch-kinematics only for arms

        rows = body.detach().cpu().reshape(body.shape[0], -1, body.shape[-1])  # (B, T, body)
        steps = rows.shape[1]
        seeds = (
            None if state is None else self.arm_joints(state.detach().cpu().reshape(len(rows), -1), OBS_STATE)
        )
        out, missed, held_back = [], 0, 0
        for i, slot in enumerate(self.slots):
            arm = self.arm(slot)
            poses = rows[..., 9 * i : 9 * (i + 1)].reshape(-1, 9)
            current = torch.tensor(arm.home) if seeds is None else seeds[i].repeat_interleave(steps, dim=0)
            q, out_of_reach = arm.joints(poses, current.to(torch.float64))
            missed += int(out_of_reach.sum())
            if seconds is not None and seeds is not None:
                step = arm.speed.to(q.dtype) * seconds
                q, limited = within_speed(q.reshape(len(rows), steps, -1), seeds[i].to(q.dtype), step)
                held_back += int(limited.sum())
            out.append(q.reshape(*body.shape[:-1], -1).to(body.device, body.dtype))
        return out, missed, held_back

    def join(
        self, body: torch.Tensor, qs: list[torch.Tensor], arms: list[torch.Tensor] | None = None
    ) -> torch.Tensor:
        """(body entries, per slot its joints in spec order and units) -> (..., action entries) in the
        robot's order and units: the inverse of `split` on actions. An armed robot's body is its tool
        poses, put into its arms' joints by `arms` (`reach`; from the arms' home when not given)."""
        columns_body, slots, arm_columns = self._indices(ACTION)
        if self.armed and arms is None:
            arms, _, _ = self.reach(body)
        out = body.new_empty((*body.shape[:-1], len(self.action_names)))
        out[..., columns_body] = body[..., :0] if self.armed else body
        for q, (columns, scale, offset) in zip([*qs, *(arms or [])], [*slots, *arm_columns], strict=True):
            out[..., columns] = ((q - offset.to(q.device, q.dtype)) / scale.to(q.device, q.dtype)).to(
                out.dtype
            )
        return out


def fits_limits(recorded: tuple[float, float], limits: tuple[float, float], scale: float = 1.0) -> bool:
    """A recorded (min, max), times `scale`, within a joint's (lower, upper), give or take the limit
    check's tolerance."""
    low, high = sorted(scale * v for v in recorded)
    slack = LIMIT_TOLERANCE * (limits[1] - limits[0])
    return limits[0] - slack <= low and high <= limits[1] + slack


def _mapped_joint(value, where: str) -> MappedJoint:
    if isinstance(value, str):
        return MappedJoint(value)
    if (
        not isinstance(value, dict)
        or not isinstance(value.get("joint"), str)
        or set(value) - {"joint", "scale", "offset"}
    ):
        raise JointMapError(
            f"{where}: give a spec joint name or {{joint: NAME, scale: S, offset: O}}, got {value!r}"
        )
    try:
        scale, offset = float(value.get("scale", 1.0)), float(value.get("offset", 0.0))
    except (TypeError, ValueError):
        raise JointMapError(f"{where}: scale and offset must be numbers, got {value!r}") from None
    if not math.isfinite(scale) or not math.isfinite(offset) or scale == 0:
        raise JointMapError(f"{where}: scale must be finite and non-zero and offset finite, got {value!r}")
    return MappedJoint(value["joint"], scale, offset)


def entry_words(name: str) -> list[str]:
    """An entry's name as lower-case words, whatever its case: `kLeftHandThumb0` -> k, left, hand, thumb,
    0; `right_hand.ring_mcp_side.pos` -> right, hand, ring, mcp, side, pos."""
    return [part.lower() for part in re.findall(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|[0-9]+", name)]


def entry_side(name: str) -> str | None:
    """The side an entry's name says: the first `left`/`right` word (`kRightHandIndex`; a two-armed
    simulator's `right_left_jaw_joint` is the right arm's), or a leading `l`/`r` (`r_thumb_mcp`)."""
    words = entry_words(name)
    named = [w for w in words if w in SIDES]
    return named[0] if named else {"l": "left", "r": "right"}.get(words[0] if words else "")


def hands_named_in(robot_type: str | None, hands: Iterable[str] | None = None) -> list[str]:
    """The hands (`hands`, else the built-ins) a `robot_type` names: all of it, or words of it
    (`arm_inspire`, `inspire+xhand`)."""
    text = (robot_type or "").lower()
    return [
        h
        for h in (builtin_hands() if hands is None else hands)
        if re.search(rf"(?<![a-z0-9]){re.escape(h.lower())}(?![a-z0-9])", text)
    ]
