"""Processor steps between a hand's joints and the policy's action space (registered, saved by name).

Preprocessor: `opfa_encode_joints` turns `observation.state` and `action` (a robot's entries, read through
the embodiment's joint map, saved here; or a merged dataset's universal layout with `observation.embodiment`)
into the policy space: body + z for `galr`, body + that hand's joints for `raw`, body + masked universal
joints for `per_embodiment`. It also leaves the batch's embodiment ids in `observation.embodiment`.

Postprocessor: `opfa_decode_joints` maps policy-space actions back to the robot's action entries (for
`galr` through the GaLR decoder), inverting the same joint map. The robot's record and the GaLR are saved
once, by the encode step; the decode step uses its pair's.

Which robot a frame comes from is said by the frame: `observation.embodiment` ids (a merged dataset), or
the robot's `robot_type`, which LeRobot passes with every frame of a robot (`robot_type.py`) and the `opfa`
env's processor with every frame of the simulator. A robot named by its hands (`inspire`, `inspire+xhand`:
the `opfa_sim` rig and env) is read in their specs' order and units; another is the trained robot its
robot_type names, the one the pipeline is pinned to (`hand`), or a one-robot policy's. A robot is named by
the embodiment of each of its hand slots (one for a one-handed robot, two for a two-armed one), and its
frames' ids are those, (B, slots). Every robot's frames go through the same code, a `JointMap`. A
postprocessor only sees the action, so it reads the robot (its ids and map) from its own preprocessor's last
batch: the encode step is LeRobot's relative-action step and the postprocessor's steps its absolute-action
steps, the one pairing LeRobot restores when it loads a pipeline pair (`make_pre_post_processors` ->
`_reconnect_relative_absolute_steps`); the relative conversion itself stays off. Each pair is its own: two
pipelines of one checkpoint drive two robots in one process.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cached_property, partial
from typing import Any

import torch
from lerobot.configs.types import PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry, TransitionKey
from lerobot.processor.relative_action_processor import (
    AbsoluteActionsProcessorStep,
    RelativeActionsProcessorStep,
)
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa.arms.pose import POSE_BODIES
from lerobot_opfa.arms.spec import arm_name, builtin_arms
from lerobot_opfa.datasets.joint_map import HANDS_SEPARATOR, SIDES, JointMap, arm_entries, hands_named_in
from lerobot_opfa.envs.scene import WRIST_JOINTS
from lerobot_opfa.features import OBS_EMBODIMENT, OBS_POINTCLOUD, ROBOT_TYPE, frame_embodiments
from lerobot_opfa.galr.frozen import encode_joints, encode_universal, relocate_hand
from lerobot_opfa.galr.model import Galr
from lerobot_opfa.hands.bundle import USER_HAND, pack, unpack
from lerobot_opfa.hands.model import LIVE_LIMIT_TOLERANCE, HandModel
from lerobot_opfa.hands.registry import builtin_hands, load_hand, load_spec
from lerobot_opfa.hands.universal import UNIVERSAL_JOINT_NAMES
from lerobot_opfa.policy.action_spaces import ACTION_SPACES, ActionSpace
from lerobot_opfa.policy.latent_cache import LatentCache

logger = logging.getLogger(__name__)

FLOATING = "floating"
"""The body (`arms.pose.POSE_BODIES`) of the simulator's floating wrist."""
LOAD_PAIRED = "load the two with lerobot's make_pre_post_processors(..., pretrained_path=...): it pairs them"
"""How a postprocessor gets its preprocessor's encode step, the one it reads the robot from."""


@ProcessorStepRegistry.register("opfa_pointcloud_batch")
@dataclass
class PointCloudBatchStep(ObservationProcessorStep):
    """Adds the batch dimension to an unbatched `observation.pointcloud` (LeRobot's batch step only
    knows state, environment state and images), after checking that it is finite and has the trained
    number of points: the point encoder would turn either into actions without a word."""

    n_points: int = 0
    """Points per cloud the policy was trained on (0: not recorded, a checkpoint saved before)."""

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        cloud = observation.get(OBS_POINTCLOUD)
        if cloud is None:
            raise ValueError(
                f"the observation has no {OBS_POINTCLOUD} (it has {', '.join(observation)}); this policy "
                "reads a point cloud (the opfa env gives one with obs_type=pointcloud, its default)"
            )
        if isinstance(cloud, torch.Tensor):
            self._check(cloud)
            if cloud.dim() == 1:
                observation[OBS_POINTCLOUD] = cloud.unsqueeze(0)
        return observation

    def _check(self, cloud: torch.Tensor) -> None:
        if cloud.dim() >= 2 and cloud.shape[-1] == 3 and cloud.shape[-2] == self.n_points:
            raise ValueError(
                f"{OBS_POINTCLOUD} has shape {tuple(cloud.shape)}; give it flattened: (..., "
                f"{3 * self.n_points}) = {self.n_points} points x 3"
            )
        if self.n_points and cloud.shape[-1] != 3 * self.n_points:
            raise ValueError(
                f"{OBS_POINTCLOUD} holds {cloud.shape[-1] / 3:g} points ({cloud.shape[-1]} values); this "
                f"policy was trained on {self.n_points} points: give it clouds of that size (the env's "
                f"`n_points`)"
            )
        bad = ~cloud.isfinite()
        if bad.any():
            point = int(bad.reshape(-1, cloud.shape[-1]).any(0).nonzero()[0]) // 3
            raise ValueError(
                f"{OBS_POINTCLOUD} is not finite (NaN or inf) at point {point} (and {int(bad.sum())} values "
                "in all): check the camera's depth and the cloud's crop"
            )

    def get_config(self) -> dict[str, Any]:
        return {"n_points": self.n_points}

    def transform_features(self, features):
        return features


@dataclass
class _HandSpace:
    """The robot record the encode step holds (and a decode step saved before it did): the embodiments,
    their hands, the GaLR and the action space (the `action_spaces.Hands` a space converts with)."""

    action_space: str = "galr"
    embodiments: list[str] = field(default_factory=list)
    hand_refs: list[str] = field(default_factory=list)
    """Per embodiment: a built-in name or a spec path (what `load_hand` takes)."""
    embodiment_joints: list[list[str]] = field(default_factory=list)
    """Per embodiment, its universal joints (the config's; read from the specs for a step saved before)."""
    wrist_dim: int = 6
    """Body entries of a policy state (a wrist pose, an arm's joints) before the hand's part."""
    action_wrist_dim: int | None = None
    """Body entries of a policy action where they are not the state's (end-effector deltas); None: the
    same."""
    galr_config: dict | None = None
    joint_maps: list[dict] = field(default_factory=list)
    """Per robot, how its vectors hold the body entries and each hand slot's joints (a bound `JointMap` as
    a dict); a step saved before: the body entries, then the joints in spec order."""
    robots: list[list[int]] = field(default_factory=list)
    """Per robot (joint map), the embodiment each of its hand slots holds; empty (saved before): one
    one-handed robot per embodiment."""
    fps: int | None = None
    """The rate the policy acts at (its training dataset's): an arm's joints move at most their velocity
    limits / fps from one action to the next. None (a step saved before): bounded by IK's own step only."""
    link: str = ""
    """Read from checkpoints saved before LeRobot paired the steps (they matched by this id); unused."""
    galr: Galr | None = field(default=None, repr=False)
    """Runtime object: built from `galr_config` when loading, weights restored by `load_state_dict`."""

    def __post_init__(self):
        if self.space.uses_galr and self.galr is None:
            if self.galr_config is None:
                raise ValueError(f"action_space '{self.action_space}' needs a GaLR (galr_config is missing)")
            self.galr = Galr(self.galr_config).eval().requires_grad_(False)
        if not self.embodiment_joints and not self.space.uses_galr:
            self.embodiment_joints = [load_spec(ref).universal_names for ref in self.hand_refs]
        if not self.joint_maps:
            self.joint_maps = [self._spec_order_map(ref).to_dict() for ref in self.hand_refs]
        if not self.robots:
            self.robots = [[index] for index in range(len(self.embodiments))]
        self._bind_maps()
        self._hands: dict[int, HandModel] = {}
        self._latent_caches: dict[int, LatentCache] = {}

    def _bind_maps(self) -> None:
        self.maps = {
            tuple(robot): JointMap.from_dict(m, f"the joint map of '{self.robot_name(robot)}'")
            for robot, m in zip(self.robots, self.joint_maps, strict=True)
        }
        self._hands_maps: dict[tuple[int, ...], JointMap] = {}

    @property
    def slot_sides(self) -> list[str | None]:
        """The side of each of the policy's hand slots, in the policy's slot order (its robots' maps list
        their slots in one order, left or right first)."""
        first = self.joint_maps[0]
        return [slot.get("side") for slot in first["slots"]] if "slots" in first else [first.get("side")]

    def robot_name(self, robot: tuple[int, ...] | list[int]) -> str:
        """A robot by its slots' hands: `inspire`, or `inspire+xhand` for two (left first, whatever the
        slots' order)."""
        by_side = sorted(
            zip(self.slot_sides, robot, strict=True), key=lambda pair: SIDES.index(pair[0] or SIDES[0])
        )
        return HANDS_SEPARATOR.join(self.embodiments[e] for _, e in by_side)

    def robot_named(self, name: str) -> tuple[int, ...]:
        """The slot embodiments of the robot `name` names (`inspire`, or `inspire+xhand`: left first), in
        the policy's slot order: slots are matched by side, never by position."""
        hands = name.split(HANDS_SEPARATOR)
        if len(hands) == 1:
            return (self.embodiments.index(hands[0]),)
        by_side = dict(zip(SIDES, hands, strict=True))
        return tuple(self.embodiments.index(by_side[side]) for side in self.slot_sides)

    def _spec_order_map(self, ref: str, joint_names: list[str] | None = None) -> JointMap:
        spec = load_spec(ref)
        joints = list(joint_names or spec.actuated_joints)
        state, action = ([f"body_{i}" for i in range(self.body_dim(k))] + joints for k in (OBS_STATE, ACTION))
        return JointMap.named_after(spec, state, action)

    def body_dim(self, key: str) -> int:
        """Body entries of the policy's `key` ("observation.state" or "action")."""
        return self.wrist_dim if key == OBS_STATE or self.action_wrist_dim is None else self.action_wrist_dim

    def trained_map(self, robot: tuple[int, ...]) -> JointMap:
        """The joint map of the trained robot whose slots hold embodiments `robot`."""
        if robot not in self.maps:
            raise ValueError(
                f"this policy drives {', '.join(map(self.robot_name, self.robots))}; it cannot drive "
                f"{self.robot_name(robot)}"
            )
        return self.maps[robot]

    def names_its_hands(self, robot_type: str | None) -> bool:
        """Whether `robot_type` is a robot named by its hands, each one of the policy's (`inspire`, or
        `inspire+xhand` for two, left first): the `opfa_sim` rig's and env's robot types."""
        hands = (robot_type or "").split(HANDS_SEPARATOR)
        return len(hands) == len(self.slot_sides) and all(hand in self.embodiments for hand in hands)

    def hands_map(self, robot: tuple[int, ...]) -> JointMap:
        """The joint map of a robot named by its hands (`names_its_hands`): its body entries, then its
        hand's joints in spec order and units; with two arms, that per side, left first
        (`joint_map.arm_entries`). Any pair of the policy's hands, one it was not trained on too (each
        slot's hand is decoded on its own)."""
        if robot not in self._hands_maps:
            floating = FLOATING if self.armed else None  # the wrist pose, from the simulator's wrist entries
            if len(robot) == 1 and floating is None:
                self._hands_maps[robot] = self._spec_order_map(self.hand_refs[robot[0]])
            elif len(robot) == 1:
                spec = load_spec(self.hand_refs[robot[0]])
                names = [*WRIST_JOINTS, *spec.actuated_joints]
                self._hands_maps[robot] = JointMap.named_after(spec, names, names, arm=floating)
            else:  # laid out left first; the policy's slots keep their own order
                arms = {
                    side: load_spec(self.hand_refs[i]) for side, i in zip(self.slot_sides, robot, strict=True)
                }
                body = (
                    list(WRIST_JOINTS)
                    if floating
                    else [f"body_{i}" for i in range(self.wrist_dim // len(robot))]
                )
                names = arm_entries({side: arms[side] for side in SIDES}, body)
                self._hands_maps[robot] = JointMap.named_after_arms(arms, names, names, arm=floating)
        return self._hands_maps[robot]

    @property
    def armed(self) -> bool:
        """Whether the policy's body is the wrists' poses (its robots' maps name their arms)."""
        return any(joint_map.armed for joint_map in self.maps.values())

    def robot_of(self, ids: torch.Tensor) -> tuple[int, ...]:
        """The one robot of a batch's (B, slots) embodiment ids: a postprocessor decodes one robot's actions
        at a time."""
        rows = {tuple(row) for row in ids.tolist()}
        if len(rows) != 1:
            named = sorted(map(self.robot_name, rows))
            raise ValueError(f"a batch to decode must come from one robot, got {named}")
        return rows.pop()

    def check_width(self, x: torch.Tensor, robot: tuple[int, ...], joint_map: JointMap, key: str) -> None:
        """A robot's state or action has the entries of its map."""
        names = joint_map.names(key)
        if x.shape[-1] != len(names):
            trained = joint_map is self.maps.get(robot)
            raise ValueError(
                f"{key} has {x.shape[-1]} entries; the '{self.robot_name(robot)}' robot "
                + (
                    f"this policy was trained on has {len(names)}: {', '.join(names)}"
                    if trained
                    else f"(named by its hands) has {len(names)}: {self.body_dim(key)} body entries, then "
                    f"{len(names) - self.body_dim(key)} joints"
                )
            )

    @property
    def space(self) -> ActionSpace:
        return ACTION_SPACES[self.action_space]

    @property
    def latent_dim(self) -> int | None:
        return None if self.galr is None else self.galr.config.latent_dim

    @property
    def slot_widths(self) -> list[int]:
        """Width of each hand slot's part of a policy vector."""
        return self.space.slot_widths(self.latent_dim, self.embodiment_joints, self.robots[0])

    def policy_width(self, key: str) -> int:
        """Width of the policy's `key`: its body entries, then each hand slot's."""
        return self.body_dim(key) + sum(self.slot_widths)

    @cached_property
    def hand_mask(self) -> torch.Tensor:
        return self.space.hand_mask(self.latent_dim, self.embodiment_joints)

    def model(self, index: int) -> HandModel:
        if index not in self._hands:
            self._hands[index] = load_hand(self.hand_refs[index])
        return self._hands[index]

    def galr_on(self, device: torch.device) -> Galr:
        if self.galr.device != device:
            self.galr.to(device)
        return self.galr

    def encode(self, index: int, q: torch.Tensor) -> torch.Tensor:
        cache = self._latent_caches.get(index)
        return self._encode(index, q) if cache is None else cache(q)

    def _encode(self, index: int, q: torch.Tensor) -> torch.Tensor:
        return encode_joints(self.galr_on(q.device), self.embodiments[index], q)

    def cache_latents(self, index: int, q: torch.Tensor) -> None:
        """Encodes hand `index`'s joint rows `q` (N, dof) of a training dataset once (latent_cache.py)."""
        self._latent_caches[index] = LatentCache(partial(self._encode, index), rows=q)

    def encode_universal(self, universal: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        return encode_universal(self.galr_on(universal.device), self.embodiments, universal, ids)

    def decode(self, index: int, z: torch.Tensor) -> torch.Tensor:
        return self.galr_on(z.device).decode(z, self.embodiments[index])

    def config_dict(self) -> dict[str, Any]:
        return {
            "action_space": self.action_space,
            "embodiments": list(self.embodiments),
            "hand_refs": list(self.hand_refs),
            "embodiment_joints": [list(joints) for joints in self.embodiment_joints],
            "wrist_dim": self.wrist_dim,
            **({} if self.action_wrist_dim is None else {"action_wrist_dim": self.action_wrist_dim}),
            "galr_config": self.galr_config,
            "joint_maps": [dict(m) for m in self.joint_maps],
            "robots": [list(robot) for robot in self.robots],
            **({} if self.fps is None else {"fps": self.fps}),
        }

    def galr_state(self, prefix: str | tuple[str, ...]) -> dict[str, torch.Tensor]:
        if self.galr is None:
            return {}
        return {k: v.detach().cpu() for k, v in self.galr.state_dict().items() if k.startswith(prefix)}

    def load_galr_state(self, state: dict[str, torch.Tensor], prefix: str | tuple[str, ...]) -> None:
        if self.galr is None:
            return
        result = self.galr.load_state_dict(state, strict=False)
        missing = [k for k in result.missing_keys if k.startswith(prefix)]
        if missing or result.unexpected_keys:
            raise ValueError(
                f"GaLR weights do not fit: missing {missing}, unexpected {result.unexpected_keys}"
            )

    def user_hands(self) -> dict[str, torch.Tensor]:
        """Each user hand (a spec path, not a built-in's name) as an archive of its files (`hands.bundle`),
        so that the checkpoint carries the hand: its spec may be gone, or on another machine."""
        return {
            f"{USER_HAND}{name}": torch.frombuffer(bytearray(pack(ref)), dtype=torch.uint8)
            for name, ref in zip(self.embodiments, self.hand_refs, strict=True)
            if ref not in builtin_hands()
        }

    def load_user_hands(self, state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Unpacks the user hands `state` carries and points the step (its hand references, joint maps and
        the GaLR's registry) at them; returns the rest of `state`."""
        for key in [k for k in state if k.startswith(USER_HAND)]:
            index = self.embodiments.index(key.removeprefix(USER_HAND))
            spec = str(unpack(state.pop(key).numpy().tobytes()))
            self.joint_maps = [
                JointMap.from_dict(m).with_hand(self.hand_refs[index], spec).to_dict()
                for m in self.joint_maps
            ]
            self.hand_refs[index] = spec
            self._hands.pop(index, None)
            if self.galr is not None:
                relocate_hand(self.galr, self.embodiments[index], spec)
        self._bind_maps()
        return state


@dataclass(frozen=True)
class FrameRobot:
    """Which robot a batch of frames came from: its embodiment ids (B, slots) and the joint map its entries
    were read through (None: a merged dataset's frames, whose robots are the trained ones). What a
    postprocessor reads from its preprocessor."""

    ids: torch.Tensor
    joint_map: JointMap | None
    state: torch.Tensor | None = None
    """The robot's state as it gave it (its entries): an armed robot's IK starts from the joints it holds."""


@ProcessorStepRegistry.register("opfa_encode_joints")
@dataclass
class OpfaEncodeJointsStep(_HandSpace, RelativeActionsProcessorStep):
    hand: str | None = None
    """The robot this pipeline drives when its frames do not say: a policy of several robots deployed
    with `lerobot-rollout` (`policy for-robot` saves it). Frames that say, and one-robot policies, need
    none."""
    accept_robot_type: str | None = None
    """A `robot_type` this pipeline drives its robot for though it names other hands: the user's word that
    the robot carries the trained hands (`policy for-robot --robot-type`)."""
    native_joint_names: list[str] = field(default_factory=list)
    """A step saved before `joint_maps`: the column order of `hand`'s joints (read, not saved)."""
    use_cached_latents: bool = False
    """Take z from a merged dataset's cache (set only when its GaLR fingerprint matches)."""
    record_for_decode: bool = False
    """The postprocessor's decode step runs on this step's record and GaLR, saved here once (the GaLR's
    decoder too). False in steps saved before, whose decode step saved its own copy."""
    decoded_state: bool = False
    """`galr`: a training frame's hand state enters as the pose the robot's hand holds when it follows the
    demonstration decoded, its GaLR round trip (`as_decoded`); a robot's live state already is that pose.
    False in steps saved before it (the config's `decoded_state` says why)."""

    def __post_init__(self):
        if self.native_joint_names and not self.joint_maps:
            self.joint_maps = [
                self._spec_order_map(ref, self.native_joint_names if e == self.hand else None).to_dict()
                for ref, e in zip(self.hand_refs, self.embodiments, strict=True)
            ]
            self.hand = None  # it named the dataset's hand, not a robot to drive
        super().__post_init__()
        self.last_frames: FrameRobot | None = None
        self._decoded_caches: dict[int, LatentCache] = {}
        self._named_hands: dict[str, frozenset[str]] = {}
        self._arms_accepted: set[tuple[tuple[int, ...], str]] = set()

    def __call__(self, transition):
        new = transition.copy()
        obs = dict(new[TransitionKey.OBSERVATION])
        state = obs[OBS_STATE].float()
        action = new.get(TransitionKey.ACTION)
        live = not isinstance(action, torch.Tensor)  # a robot's (training frames carry their action)
        joint_map, robot_state = None, None
        if OBS_EMBODIMENT in obs:
            ids = frame_embodiments(obs[OBS_EMBODIMENT], len(self.robots[0])).to(state.device)

            def convert(x, key):
                return self._from_universal(x, ids, key, live)
        else:
            robot, joint_map = self.robot_of_frames(
                (new.get(TransitionKey.COMPLEMENTARY_DATA) or {}).get(ROBOT_TYPE)
            )
            ids = torch.tensor(robot, device=state.device).expand(len(state), -1)
            robot_state = state.reshape(len(ids), -1)

            def convert(x, key):
                return self._from_robot(x, robot, joint_map, key, live)

        obs[OBS_STATE] = convert(state, OBS_STATE)
        if isinstance(action, torch.Tensor):
            new[TransitionKey.ACTION] = convert(action.float(), ACTION)
        obs[OBS_EMBODIMENT] = ids
        self.last_frames = FrameRobot(ids, joint_map, robot_state)
        new[TransitionKey.OBSERVATION] = obs
        return new

    def robot_of_frames(self, robot_type: str | None) -> tuple[tuple[int, ...], JointMap]:
        """The robot a batch of a robot's frames came from (the embodiment of each of its slots) and the map
        they are read through. A robot named by its hands (`names_its_hands`: the `opfa_sim` rig and env,
        whose `robot_type` LeRobot passes with each frame, `robot_type.py`) is read in its hands' spec order
        and units (`hands_map`); another is a trained robot (`trained_robot`)."""
        if self.names_its_hands(robot_type):
            robot = self.robot_named(robot_type)
            return robot, self.hands_map(robot)
        robot = self.trained_robot(robot_type)
        return robot, self.trained_map(robot)

    def trained_robot(self, robot_type: str | None = None) -> tuple[int, ...]:
        """The trained robot the pipeline drives: the one it is pinned to (`hand`), its one robot, or the one
        a deployed robot's `robot_type` names; a `robot_type` that names other hands than that robot's is
        refused (`accept_robot_type` overrides)."""
        if self.hand is not None:
            robot = self.pinned_robot(self.hand)
        else:
            typed = self._robots_of_type(robot_type)
            if len(self.robots) != 1 and not typed:
                self._check_robot_type(None, robot_type)
            if len(self.robots) != 1 and len(typed) != 1:
                raise ValueError(
                    f"this policy drives several robots ({', '.join(map(self.robot_name, self.robots))}) and "
                    "the frames do not say which: give them the robot's robot_type (LeRobot's robots do), or "
                    "pin the pipeline to one: `lerobot-opfa policy for-robot --hand NAME`"
                )
            robot = tuple(self.robots[0]) if len(self.robots) == 1 else typed[0]
        self._check_robot_type(robot, robot_type)
        self._check_arm(robot, robot_type)
        return robot

    def _check_arm(self, robot: tuple[int, ...], robot_type: str | None) -> None:
        """A deployed robot whose `robot_type` names another built-in arm than the trained robot's, or an arm
        where the trained robot was the simulator's floating wrist, is refused: its arm's joints would be read
        as the other body's, as many of them or not (`accept_robot_type` overrides). A trained robot whose
        body entries are not modelled (an arm's joints kept as they are) says nothing either way. Judged once
        per robot type: a deployed robot gives it with every frame."""
        if (
            not robot_type
            or robot_type == self.accept_robot_type
            or (robot, robot_type) in self._arms_accepted
        ):
            return
        named = set(hands_named_in(robot_type, builtin_arms()))
        joint_map = self.maps[robot]
        trained = {arm_name(slot.arm) for slot in joint_map.slots if slot.arm not in (None, *POSE_BODIES)}
        floating = any(slot.arm == FLOATING for slot in joint_map.slots) or (
            not joint_map.armed and set(WRIST_JOINTS) <= set(joint_map.body_names(OBS_STATE))
        )
        if named and (named != trained if trained else floating):
            mine = f"'{self.robot_name(robot)}' on " + (", ".join(sorted(trained)) or "the floating wrist")
            raise ValueError(
                f"this policy drives {mine}, but the robot's robot_type '{robot_type}' names arm(s) "
                f"{', '.join(sorted(named))}: its joints would be read as another body's; deploy a policy "
                f"trained on this arm, or if the robot is the trained one, say so: `lerobot-opfa policy "
                f"for-robot --policy CHECKPOINT --hand {self.robot_name(robot)} --robot-type {robot_type} "
                "--output OUT`"
            )
        self._arms_accepted.add((robot, robot_type))

    def pinned_robot(self, name: str) -> tuple[int, ...]:
        """The trained robot `name` names (`inspire`, or `inspire+xhand`, left first)."""
        names = [self.robot_name(robot) for robot in self.robots]
        if name not in names:
            raise ValueError(
                f"this policy drives {', '.join(names)}; it cannot drive hand '{name}' (a policy acts for "
                "the robots it was trained on, and for a robot named by other pairs of their hands)"
            )
        return self.robot_named(name)

    def _robots_of_type(self, robot_type: str | None) -> list[tuple[int, ...]]:
        """The trained robots a deployed robot's `robot_type` says it is."""
        return [
            tuple(robot) for robot in self.robots if robot_type and self._is_of_type(tuple(robot), robot_type)
        ]

    def _is_of_type(self, robot: tuple[int, ...], robot_type: str) -> bool:
        """Whether `robot_type` is `robot`'s: its name, the robot_type its joint map confirms, or a name
        that says exactly its hands (`arm_inspire`)."""
        named = self.hands_named(robot_type)
        confirmed = self.maps[robot].robot_type if robot in self.maps else None
        return robot_type in (self.robot_name(robot), confirmed) or named == {
            self.embodiments[e] for e in robot
        }

    def hands_named(self, robot_type: str) -> frozenset[str]:
        """The built-in or policy hands a `robot_type` names (`joint_map.hands_named_in`), read once per
        robot type: a deployed robot gives its type with every frame."""
        if robot_type not in self._named_hands:
            hands = {*builtin_hands(), *self.embodiments}
            self._named_hands[robot_type] = frozenset(hands_named_in(robot_type, hands))
        return self._named_hands[robot_type]

    def _check_robot_type(self, robot: tuple[int, ...] | None, robot_type: str | None) -> None:
        """A deployed robot whose `robot_type` names other hands than `robot`'s (None: than any trained
        robot's) is refused: its joints would be read as another hand's without a word (a gripper's jaw in
        metres as another's knuckle in radians). A robot_type that names no hand (`so101_follower`) says
        nothing either way."""
        if not robot_type or robot_type == self.accept_robot_type:
            return
        if robot is not None and self._is_of_type(robot, robot_type):
            return
        named = self.hands_named(robot_type)
        if named:
            mine = (
                self.robot_name(robot) if robot is not None else ", ".join(map(self.robot_name, self.robots))
            )
            raise ValueError(
                f"this policy drives '{mine}', but the robot's robot_type '{robot_type}' names hand(s) "
                f"{', '.join(sorted(named))}: its joints would be read as '{mine}''s; deploy a policy "
                f"trained on its hand, or if the robot does carry '{mine}', say so: `lerobot-opfa policy "
                f"for-robot --policy CHECKPOINT --hand {mine if robot else 'NAME'} --robot-type {robot_type} "
                "--output OUT`"
            )

    def _from_robot(
        self, x: torch.Tensor, robot: tuple[int, ...], joint_map: JointMap, key: str, live: bool
    ) -> torch.Tensor:
        """A robot's state or action -> the policy space (body entries, then each hand slot's part). A live
        robot's joints must be near its hands' limits: a reading in other units would be encoded into a
        state the policy never saw, without a word (NaN is the state guard's, which names the entry)."""
        self.check_width(x, robot, joint_map, key)
        if live and joint_map.armed and x.isfinite().all():
            joint_map.check_arms(x, key, f"{OBS_STATE} of the robot (through {joint_map.source})")
        body, qs = joint_map.split(x, key)
        parts = [body]
        for index, q, slot in zip(robot, qs, joint_map.slots, strict=True):
            if live and q.isfinite().all():
                source = f"{OBS_STATE} of the robot (through {joint_map.source})"
                source += f", its {slot.side} hand" if slot.side else ""
                self.model(index).check_within_limits(
                    q.reshape(-1, q.shape[-1]), source, LIVE_LIMIT_TOLERANCE
                )
            hand = self.space.from_joints(self, index, q)
            parts.append(self.as_decoded(index, hand) if self._decodes_state(key, live) else hand)
        return torch.cat(parts, dim=-1)

    def _decodes_state(self, key: str, live: bool) -> bool:
        return self.decoded_state and self.space.uses_galr and key == OBS_STATE and not live

    def as_decoded(self, index: int, z: torch.Tensor) -> torch.Tensor:
        """Latents (..., latent) of hand `index`'s demonstrated states -> those of the poses the robot's hand
        holds when it follows them decoded, encode(decode(z)) (`decoded_state`); each once per row."""
        if index not in self._decoded_caches:

            def round_trip(rows: torch.Tensor) -> torch.Tensor:
                return self._encode(index, self.decode(index, rows))

            self._decoded_caches[index] = LatentCache(round_trip)
        return self._decoded_caches[index](z, keep=True)

    # --- merged layout: body, then per slot the universal joints [+ cached z] ---------------------------
    def _from_universal(self, x: torch.Tensor, ids: torch.Tensor, key: str, live: bool) -> torch.Tensor:
        """A merged dataset's rows (`layout.merged_names`) of robots with slot embodiments `ids` (B, slots)
        -> the policy space. Rows without the cached z (a noisy copy) have them encoded."""
        w, u, slots = self.wrist_dim, len(UNIVERSAL_JOINT_NAMES), ids.shape[-1]
        cached = self.use_cached_latents and x.shape[-1] == w + slots * (u + self.latent_dim)
        width = (x.shape[-1] - w) // slots
        parts = [x[..., :w]]
        for slot, start in enumerate(range(w, x.shape[-1], width)):
            if cached:
                hand = x[..., start + u : start + width]
            else:
                hand = self.space.from_universal(self, x[..., start : start + u], ids[:, slot])
            if self._decodes_state(key, live):
                hand = hand.clone()
                for index in ids[:, slot].unique().tolist():
                    rows = ids[:, slot] == index
                    hand[rows] = self.as_decoded(index, hand[rows])
            parts.append(hand)
        return torch.cat(parts, dim=-1)

    def get_config(self) -> dict[str, Any]:
        pinned = {} if self.hand is None else {"hand": self.hand}
        if self.accept_robot_type is not None:
            pinned["accept_robot_type"] = self.accept_robot_type
        flags = {
            "use_cached_latents": self.use_cached_latents,
            "record_for_decode": self.record_for_decode,
            "decoded_state": self.decoded_state,
        }
        return {**self.config_dict(), **flags, **pinned}

    @property
    def _galr_parts(self) -> tuple[str, ...]:
        """The GaLR weights the step holds: the encoder, and the decoder too where it decodes (its decode
        step, `decoded_state`)."""
        return ("encoder.", "decoder.") if self.record_for_decode or self.decoded_state else ("encoder.",)

    def state_dict(self) -> dict[str, torch.Tensor]:
        return self.galr_state(self._galr_parts) | self.user_hands()

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.load_galr_state(self.load_user_hands(state), self._galr_parts)

    def transform_features(self, features):
        for kind, key in ((PipelineFeatureType.OBSERVATION, OBS_STATE), (PipelineFeatureType.ACTION, ACTION)):
            if key in features.get(kind, {}):
                width = self.policy_width(key)
                features[kind][key] = PolicyFeature(type=features[kind][key].type, shape=(width,))
        return features


def paired_frames(step: AbsoluteActionsProcessorStep, batch: int, embodiments: list[str]) -> FrameRobot:
    """The robot of the batch a postprocessor step's preprocessor saw last (a one-robot policy's when it
    has seen none)."""
    encoder = step.relative_step if isinstance(step.relative_step, OpfaEncodeJointsStep) else None
    own = getattr(step, "embodiments", None)
    if encoder is not None and own and list(own) != list(encoder.embodiments):
        raise ValueError(
            f"this postprocessor is another checkpoint's: it acts for {', '.join(own)}, its preprocessor for "
            f"{', '.join(encoder.embodiments)}; {LOAD_PAIRED}, from one checkpoint folder"
        )
    seen = None if encoder is None else encoder.last_frames
    if seen is not None and len(seen.ids) == batch:
        return seen
    robots = [[index] for index in range(len(embodiments))] if encoder is None else encoder.robots
    if len(robots) == 1:
        return FrameRobot(torch.tensor(robots[0]).expand(batch, -1), joint_map=None)
    raise ValueError(
        "this postprocessor needs the robot its preprocessor saw: run the preprocessor on the observation "
        f"first, and {LOAD_PAIRED}"
    )


@ProcessorStepRegistry.register("opfa_decode_joints")
@dataclass
class OpfaDecodeJointsStep(_HandSpace, AbsoluteActionsProcessorStep):
    """Policy-space actions (B, [T], body + ...) -> the attached robot's action entries, in its order and
    units (its joint map inverted). The robot's record and the GaLR are its encode step's
    (`relative_step`), saved there once; a step saved before that carries its own copy (the `_HandSpace`
    fields of its config) and runs on it."""

    action_space: str | None = None
    """Set only in a step saved with its own copy of the record."""

    def __post_init__(self):
        if self.action_space is not None:
            super().__post_init__()
        self._unreachable = self._held_back = 0

    def reset(self) -> None:
        """A new episode: its first pose out of an arm's reach, and its first action held back to the
        arm's speed, are reported again."""
        self._unreachable = self._held_back = 0

    @property
    def hands(self) -> _HandSpace:
        """The record and GaLR this step decodes with: its own copy, else its encode step's."""
        if self.action_space is not None:
            return self
        if not isinstance(self.relative_step, OpfaEncodeJointsStep):
            raise ValueError(f"this postprocessor decodes with its preprocessor's robot: {LOAD_PAIRED}")
        return self.relative_step

    def __call__(self, transition):
        new = transition.copy()
        action = new[TransitionKey.ACTION]
        hands = self.hands
        frames = paired_frames(self, len(action), hands.embodiments)
        robot = hands.robot_of(frames.ids)
        wrist, *parts = action.split([hands.body_dim(ACTION), *hands.slot_widths], dim=-1)
        qs = [hands.space.to_joints(hands, index, part) for index, part in zip(robot, parts, strict=True)]
        joint_map = frames.joint_map or hands.trained_map(robot)
        arms = None
        if joint_map.armed:
            seconds = None if hands.fps is None else 1.0 / hands.fps
            arms, missed, held_back = joint_map.reach(wrist, frames.state, seconds)
            if missed and not self._unreachable:
                logger.warning(
                    "%d wrist pose(s) the policy asked for are out of the arm's reach (%s); the arm goes to "
                    "the nearest it reaches (reported once per episode)", missed, joint_map.source,
                )  # fmt: skip
            if held_back and not self._held_back:
                logger.warning(
                    "%d action(s) would move the arm (%s) faster than its velocity limits at %s fps; each "
                    "goes as far as the limits allow (reported once per episode)", held_back,
                    joint_map.source, hands.fps,
                )  # fmt: skip
            self._unreachable += missed
            self._held_back += held_back
        new[TransitionKey.ACTION] = joint_map.join(wrist, qs, arms)
        return new

    def get_config(self) -> dict[str, Any]:
        return {} if self.action_space is None else self.config_dict()

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {} if self.action_space is None else self.galr_state("decoder.") | self.user_hands()

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.load_galr_state(self.load_user_hands(state), "decoder.")

    def transform_features(self, features):
        return features
