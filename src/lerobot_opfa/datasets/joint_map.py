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
joints (or `<joint>.pos`) needs no file (`JointMap.named_after`). One hand per frame; a second would be a
second list of joints here, nothing elsewhere.
"""

from __future__ import annotations

import difflib
import logging
import math
import re
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

POSITION_SUFFIX = ".pos"
"""LeRobot's robots name a motor's position entry `<motor>.pos` (what `lerobot-record` writes)."""


def joint_of(entry: str) -> str:
    """The joint an entry named after it stands for: itself, or `<joint>.pos`."""
    return entry.removesuffix(POSITION_SUFFIX)


class JointMapError(ValueError):
    """A joint map that does not fit its dataset or its hand; the message names the map and the entry."""


@dataclass(frozen=True)
class MappedJoint:
    joint: str
    """The spec's (model) joint name."""
    scale: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class JointMap:
    hand: str
    """What `load_hand` takes: a built-in name or a spec path."""
    joints: dict[str, MappedJoint]
    """Entry of both the state and the action -> the spec joint it holds."""
    state_joints: dict[str, MappedJoint] = field(default_factory=dict)
    action_joints: dict[str, MappedJoint] = field(default_factory=dict)
    """Entries of only the state, or only the action -> the spec joint each holds (`key_joints`)."""
    drop: tuple[str, ...] = ()
    robot_type: str | None = None
    """The dataset `robot_type` the map is confirmed for when it names another hand (`check_robot_type`)."""
    source: str = "joint map"
    """Where the map came from, for messages."""
    state_names: tuple[str, ...] = ()
    action_names: tuple[str, ...] = ()
    """The robot's entries the map is bound to (`bind`); empty for a map as read from its file."""
    _columns: dict = field(default_factory=dict, compare=False, repr=False)

    # --- reading and writing ----------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> JointMap:
        path = Path(path)
        try:
            raw = read_yaml(path, "joint map")
        except YamlFileError as err:
            raise JointMapError(str(err)) from None
        hand = raw.get("hand") if isinstance(raw, dict) else None
        if isinstance(hand, str) and hand not in builtin_hands() and not Path(hand).is_absolute():
            raw["hand"] = str((path.parent / hand).resolve())
        return cls.from_dict(raw, str(path))

    @classmethod
    def from_dict(cls, raw, source: str = "joint map") -> JointMap:
        tables = ("joints", "state_joints", "action_joints")
        if not isinstance(raw, dict) or not any(raw.get(t) for t in tables):
            raise JointMapError(
                f"{source}: needs a mapping 'joints' of dataset entry -> spec joint (or, where the state "
                "and the action hold the hand under different entries, 'state_joints' and 'action_joints')"
            )
        if not isinstance(raw.get("hand"), str):
            raise JointMapError(f"{source}: needs 'hand', a built-in hand's name or a spec.yaml path")
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
        drop = raw.get("drop") or []
        if not isinstance(drop, list):
            raise JointMapError(f"{source}: 'drop' must be a list of entry names")
        unknown = set(raw) - {*tables, "hand", "drop", "robot_type", "state_names", "action_names"}
        if unknown:
            raise JointMapError(
                f"{source}: unknown field(s) {sorted(unknown)} (hand, joints, state_joints, action_joints, "
                "drop, robot_type)"
            )
        robot_type = raw.get("robot_type")
        if robot_type is not None and not isinstance(robot_type, str):
            raise JointMapError(f"{source}: 'robot_type' must be a dataset's robot_type, got {robot_type!r}")
        return cls(
            hand=raw["hand"],
            joints=joints["joints"],
            state_joints=joints["state_joints"],
            action_joints=joints["action_joints"],
            drop=tuple(map(str, drop)),
            robot_type=robot_type,
            source=source,
            state_names=tuple(raw.get("state_names", ())),
            action_names=tuple(raw.get("action_names", ())),
        )

    def to_dict(self) -> dict:
        """What a checkpoint or a merged dataset saves (with the names it is bound to)."""

        def table(joints: dict[str, MappedJoint]) -> dict:
            return {e: {"joint": j.joint, "scale": j.scale, "offset": j.offset} for e, j in joints.items()}

        apart = {
            name: table(joints)
            for name, joints in (("state_joints", self.state_joints), ("action_joints", self.action_joints))
            if joints
        }
        return {
            "hand": self.hand,
            "joints": table(self.joints),
            **apart,
            "drop": list(self.drop),
            **({"robot_type": self.robot_type} if self.robot_type is not None else {}),
            "state_names": list(self.state_names),
            "action_names": list(self.action_names),
        }

    @classmethod
    def named_after(cls, spec: HandSpec, state_names: list[str], action_names: list[str]) -> JointMap:
        """The map of a robot whose hand entries carry the spec's joint names (or LeRobot's `<joint>.pos`),
        in the spec's units."""
        entries = {**{joint_of(n): n for n in action_names}, **{n: n for n in action_names}}
        joints = {entries.get(j, j): MappedJoint(j) for j in spec.actuated_joints}
        return cls(hand_ref(spec), joints, source=f"hand '{spec.name}'").bind(state_names, action_names)

    # --- binding to a robot's entries -----------------------------------------------------------------
    def bind(self, state_names: list[str], action_names: list[str]) -> JointMap:
        """This map checked against a robot's (a dataset's) state and action entries and the hand's spec."""
        state, action = list(map(str, state_names)), list(map(str, action_names))
        spec = load_spec(self.hand)
        for key, names in ((OBS_STATE, state), (ACTION, action)):
            for entry in self.key_joints(key):
                if entry not in names:
                    near = difflib.get_close_matches(entry, names, n=3)
                    raise JointMapError(
                        f"{self.source}: entry {entry!r} is not in the dataset's {key}"
                        + (
                            f" (closest: {', '.join(map(repr, near))})"
                            if near
                            else f" ({len(names)} entries: {names[:8]} ...)"
                        )
                        + (
                            "; an entry of only the state or only the action goes under 'state_joints' or "
                            "'action_joints'"
                            if entry in self.joints
                            else ""
                        )
                    )
            held = [j.joint for j in self.key_joints(key).values()]
            unknown = [j for j in held if j not in spec.joints]
            twice = sorted({j for j in held if held.count(j) > 1})
            missing = [j for j in spec.actuated_joints if j not in held]
            if unknown or twice or missing:
                raise JointMapError(
                    f"{self.source}: must name each joint of hand '{spec.name}' once in {key} "
                    f"({', '.join(spec.actuated_joints)}): unknown {unknown}, twice {twice}, "
                    f"missing {missing}"
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
        return replace(self, state_names=tuple(state), action_names=tuple(action), _columns={})

    def key_joints(self, key: str) -> dict[str, MappedJoint]:
        """`key`'s entries ("observation.state" or "action") that hold the hand's joints."""
        return {**self.joints, **(self.state_joints if key == OBS_STATE else self.action_joints)}

    def check_robot_type(self, robot_type: str | None) -> None:
        """Refuses a map for another hand than the one the dataset's `robot_type` names (`inspire`, or a word
        of `arm_inspire`), unless the map confirms that robot_type: the policy would learn the wrong hand
        without a word."""
        named, hand = hands_named_in(robot_type), self.spec.name
        if not named or hand in named or self.robot_type == robot_type:
            return
        other = max(named, key=len)  # `inspire_tactile` rather than the `inspire` inside it
        raise JointMapError(
            f"{self.source}: maps hand '{hand}', but the dataset's robot_type '{robot_type}' names hand "
            f"'{other}'; use a map for '{other}', or, if this robot does carry '{hand}', confirm it with the "
            f"line `robot_type: {robot_type}` in the map"
        )

    def check_spans(self, x: torch.Tensor, key: str, lower: torch.Tensor, upper: torch.Tensor) -> None:
        """Refuses a scale that squeezes a joint into less than `SPAN_FRACTION` of its range (`lower`,
        `upper`: the hand's limits in spec order) while its entry as recorded spans more, within those
        limits: a degrees scale on entries already in radians, which the limit check lets through. Any other
        scaled joint that moves over less than `SPAN_FRACTION` of its range is a warning naming it: a scale
        too small, or a joint the demos barely move."""
        names, by_joint = self.names(key), {j.joint: (e, j) for e, j in self.key_joints(key).items()}
        x = x.detach().to("cpu", torch.float64).reshape(-1, x.shape[-1])
        if not len(x):
            return
        for i, joint in enumerate(self.spec.actuated_joints):
            entry, mapped = by_joint[joint]
            raw, low, high = x[:, names.index(entry)], float(lower[i]), float(upper[i])
            width, recorded = high - low, float(raw.max() - raw.min())
            span = abs(mapped.scale) * recorded
            within = fits_limits((float(raw.min()), float(raw.max())), (low, high))
            if mapped.scale != 1 and span < SPAN_FRACTION * width <= recorded and within:
                raise JointMapError(
                    f"{self.source}: entry {entry!r} with scale {mapped.scale:g} moves joint '{joint}' over "
                    f"{span:.3g} of its range {width:.3g} ([{low:.3g}, {high:.3g}]) in {key}, while as "
                    f"recorded it spans {recorded:.3g} within those limits: it is in the spec's units "
                    "already (radians, metres); use scale 1, or invert the scale if it is the wrong way round"
                )
            if mapped.scale != 1 and span < SPAN_FRACTION * width:
                logger.warning(
                    "%s: entry %r with scale %g moves joint '%s' over %.3g of its range %.3g in %s (under a "
                    "tenth): check the scale, or that the demos move this joint",
                    self.source, entry, mapped.scale, joint, span, width, key,
                )  # fmt: skip

    def body_names(self, key: str) -> list[str]:
        """`key`'s entries besides the hand's joints (and the dropped ones), in its order: the policy models
        them as they are."""
        joints = self.key_joints(key)
        return [n for n in self.names(key) if n not in joints and n not in self.drop]

    @property
    def spec(self) -> HandSpec:
        return load_spec(self.hand)

    def _indices(self, key: str) -> tuple[list[int], list[int], torch.Tensor, torch.Tensor]:
        """(body columns, joint columns in spec order, scale, offset) of `key`'s vectors."""
        if key not in self._columns:
            if not self.action_names:
                raise JointMapError(f"{self.source}: not bound to a robot's entries (JointMap.bind)")
            names = self.names(key)
            by_joint = {j.joint: (e, j) for e, j in self.key_joints(key).items()}
            order = [by_joint[j] for j in self.spec.actuated_joints]
            self._columns[key] = (
                [names.index(n) for n in self.body_names(key)],
                [names.index(e) for e, _ in order],
                torch.tensor([j.scale for _, j in order], dtype=torch.float64),
                torch.tensor([j.offset for _, j in order], dtype=torch.float64),
            )
        return self._columns[key]

    def names(self, key: str) -> list[str]:
        """The robot's entries of `key` ("observation.state" or "action")."""
        return list(self.state_names if key == OBS_STATE else self.action_names)

    def split(self, x: torch.Tensor, key: str) -> tuple[torch.Tensor, torch.Tensor]:
        """(..., robot entries) of `key` ("observation.state" or "action") -> (body entries, the hand's joints
        in spec order and units)."""
        names = self.names(key)
        if x.shape[-1] != len(names):
            raise ValueError(
                f"{key} has {x.shape[-1]} entries; the robot this policy was trained on has {len(names)} "
                f"({self.source}: {', '.join(names[:6])} ...)"
            )
        body, columns, scale, offset = self._indices(key)
        q = x[..., columns] * scale.to(x.device, x.dtype) + offset.to(x.device, x.dtype)
        return x[..., body], q

    def join(self, body: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """(body entries, joints in spec order and units) -> (..., action entries) in the robot's order and
        units: the inverse of `split` on actions."""
        columns_body, columns, scale, offset = self._indices(ACTION)
        out = body.new_empty((*body.shape[:-1], len(self.action_names)))
        out[..., columns_body] = body
        out[..., columns] = ((q - offset.to(q.device, q.dtype)) / scale.to(q.device, q.dtype)).to(out.dtype)
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


def hands_named_in(robot_type: str | None) -> list[str]:
    """The built-in hands a dataset's `robot_type` names: all of it, or words of it (`arm_inspire`)."""
    text = (robot_type or "").lower()
    return [h for h in builtin_hands() if re.search(rf"(?<![a-z0-9]){re.escape(h)}(?![a-z0-9])", text)]
