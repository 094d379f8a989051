"""Processor steps between a hand's joints and the policy's action space (registered, saved by name).

Preprocessor: `opfa_encode_joints` turns `observation.state` and `action` (a robot's entries, read through
the embodiment's joint map, saved here; or a merged dataset's universal layout with `observation.embodiment`)
into the policy space: body + z for `galr`, body + that hand's joints for `raw`, body + masked universal
joints for `per_embodiment`. It also leaves the batch's embodiment ids in `observation.embodiment`.

Postprocessor: `opfa_decode_joints` maps policy-space actions back to the robot's action entries (for
`galr` through the GaLR decoder), inverting the same joint map. A postprocessor only sees the action, so it
reads which hand produced it from its preprocessor partner: both carry the same `link` id (saved in both
JSON configs), the same way LeRobot's relative/absolute action steps pair up. Two pipelines loaded from one
checkpoint share the link: when both preprocessors have seen observations, a postprocessor cannot tell them
apart and refuses; give each postprocessor its hand instead (`hand`, e.g. through `postprocessor_overrides`).
"""

from __future__ import annotations

import gc
import weakref
from dataclasses import dataclass, field
from functools import cached_property, partial
from typing import Any

import torch
from lerobot.configs.types import PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStep, ProcessorStepRegistry, TransitionKey
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa.datasets.joint_map import JointMap
from lerobot_opfa.features import OBS_EMBODIMENT, OBS_HAND, OBS_POINTCLOUD, batch_embodiments
from lerobot_opfa.galr.frozen import encode_joints, encode_universal, relocate_hand
from lerobot_opfa.galr.model import Galr
from lerobot_opfa.hands.bundle import pack, unpack
from lerobot_opfa.hands.model import LIVE_LIMIT_TOLERANCE, HandModel
from lerobot_opfa.hands.registry import builtin_hands, load_hand, load_spec
from lerobot_opfa.hands.universal import UNIVERSAL_JOINT_NAMES
from lerobot_opfa.policy.action_spaces import ACTION_SPACES, ActionSpace
from lerobot_opfa.policy.deferred import defer
from lerobot_opfa.policy.latent_cache import LatentCache

USER_HAND = "user_hand."
"""State-dict key prefix of a user hand's archive (`hands.bundle`), by the hand's name."""

_ENCODERS: dict[str, weakref.WeakValueDictionary[int, OpfaEncodeJointsStep]] = {}
"""link id -> the live preprocessor steps that have processed a batch (their postprocessor partners read
the embodiment ids from the one there is)."""


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
    """What both joint steps share: the embodiments, their hands, the GaLR and the action space (the
    `action_spaces.Hands` a space converts with)."""

    action_space: str = "galr"
    embodiments: list[str] = field(default_factory=list)
    hand_refs: list[str] = field(default_factory=list)
    """Per embodiment: a built-in name or a spec path (what `load_hand` takes)."""
    embodiment_joints: list[list[str]] = field(default_factory=list)
    """Per embodiment, its universal joints (the config's; read from the specs for a step saved before)."""
    wrist_dim: int = 6
    """Body entries of a policy state or action (a wrist pose, an arm's joints) before the hand's part."""
    galr_config: dict | None = None
    link: str = ""
    joint_maps: list[dict] = field(default_factory=list)
    """Per embodiment, how its robot's vectors hold the body entries and the hand's joints (a bound
    `JointMap` as a dict); a step saved before: the body entries, then the joints in spec order."""
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
        self.maps = [
            JointMap.from_dict(m, f"the joint map of '{e}'")
            for m, e in zip(self.joint_maps, self.embodiments, strict=True)
        ]
        self._hands: dict[int, HandModel] = {}
        self._latent_caches: dict[int, LatentCache] = {}

    def _spec_order_map(self, ref: str, joint_names: list[str] | None = None) -> JointMap:
        spec = load_spec(ref)
        names = [f"body_{i}" for i in range(self.wrist_dim)] + list(joint_names or spec.actuated_joints)
        return JointMap.named_after(spec, names, names)

    def check_width(self, x: torch.Tensor, index: int, key: str, spec_order: bool) -> None:
        """A robot's state or action has the entries of the embodiment's robot; one in spec order (this
        package's env) the body entries, then the hand's joints."""
        expected = self.wrist_dim + self.model(index).dof if spec_order else len(self.maps[index].names(key))
        if x.shape[-1] != expected:
            hand = self.embodiments[index]
            raise ValueError(
                f"{key} has {x.shape[-1]} entries; the '{hand}' robot this policy was trained on has "
                f"{expected}: "
                + (
                    f"{self.wrist_dim} body entries, then {self.model(index).dof} joints"
                    if spec_order
                    else ", ".join(self.maps[index].names(key))
                )
            )

    def to_robot(self, index: int, body: torch.Tensor, q: torch.Tensor, spec_order: bool) -> torch.Tensor:
        """Body entries and joints (spec order and units) -> the robot's action vector."""
        if spec_order:
            return torch.cat([body, q.to(body.dtype)], dim=-1)
        return self.maps[index].join(body, q)

    @property
    def space(self) -> ActionSpace:
        return ACTION_SPACES[self.action_space]

    @property
    def latent_dim(self) -> int | None:
        return None if self.galr is None else self.galr.config.latent_dim

    @cached_property
    def policy_width(self) -> int:
        """Width of a policy-space state or action: the wrist's entries, then the space's."""
        return self.wrist_dim + self.space.hand_width(self.latent_dim, self.embodiment_joints)

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
        return self._encode(index, q) if cache is None else cache.encode(q, partial(self._encode, index))

    def _encode(self, index: int, q: torch.Tensor) -> torch.Tensor:
        return encode_joints(self.galr_on(q.device), self.embodiments[index], q)

    def cache_latents(self, index: int, q: torch.Tensor) -> None:
        """Encodes hand `index`'s joint rows `q` (N, dof) of a training dataset once (latent_cache.py)."""
        self._latent_caches[index] = LatentCache(q, partial(self._encode, index))

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
            "galr_config": self.galr_config,
            "link": self.link,
            "joint_maps": [dict(m) for m in self.joint_maps],
        }

    def galr_state(self, prefix: str) -> dict[str, torch.Tensor]:
        if self.galr is None:
            return {}
        return {k: v.detach().cpu() for k, v in self.galr.state_dict().items() if k.startswith(prefix)}

    def load_galr_state(self, state: dict[str, torch.Tensor], prefix: str) -> None:
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
            self.hand_refs[index] = self.joint_maps[index]["hand"] = spec
            self.maps[index] = JointMap.from_dict(self.joint_maps[index], self.maps[index].source)
            self._hands.pop(index, None)
            if self.galr is not None:
                relocate_hand(self.galr, self.embodiments[index], spec)
        return state

    def single_id(self, ids: torch.Tensor) -> int:
        unique = ids.unique()
        if len(unique) != 1:
            names = [self.embodiments[i] for i in unique.tolist()]
            raise ValueError(f"a batch to decode must come from one hand, got {names}")
        return int(unique[0])


@ProcessorStepRegistry.register("opfa_encode_joints")
@dataclass
class OpfaEncodeJointsStep(_HandSpace, ProcessorStep):
    hand: str | None = None
    """Hand of batches that carry no embodiment id (a robot's vectors). None: the trained hand whose robot
    has the state's width, or an error when several do."""
    native_joint_names: list[str] = field(default_factory=list)
    """A step saved before `joint_maps`: the column order of `hand`'s joints (read, not saved)."""
    use_cached_latents: bool = False
    """Take z from a merged dataset's cache (set only when its GaLR fingerprint matches)."""

    def __post_init__(self):
        if self.native_joint_names and not self.joint_maps:
            self.joint_maps = [
                self._spec_order_map(ref, self.native_joint_names if e == self.hand else None).to_dict()
                for ref, e in zip(self.hand_refs, self.embodiments, strict=True)
            ]
        super().__post_init__()
        self.last_ids: torch.Tensor | None = None
        self.last_in_spec_order = False

    def __call__(self, transition):
        new = transition.copy()
        obs = dict(new[TransitionKey.OBSERVATION])
        state = obs[OBS_STATE].float()
        action = new.get(TransitionKey.ACTION)
        hand = obs.pop(OBS_HAND, None)
        spec_order = hand is not None  # this package's env: the wrist, then the joints in spec order
        if OBS_EMBODIMENT in obs:
            ids = batch_embodiments(obs[OBS_EMBODIMENT]).to(state.device)

            def convert(x, key):
                return self._from_universal(x, ids)
        else:
            index = self._hand_index(hand) if hand is not None else self._native_index(state.shape[-1])
            self.check_width(state, index, OBS_STATE, spec_order)  # now, even when the encode is deferred
            if not isinstance(action, torch.Tensor):  # a live robot's (training frames are checked whole)
                self.check_robot_state(state, index, spec_order)
            ids = torch.full((len(state),), index, dtype=torch.long, device=state.device)

            def convert(x, key):
                return self._from_robot(x, index, key, spec_order)

        if isinstance(action, torch.Tensor):
            obs[OBS_STATE] = convert(state, OBS_STATE)
            new[TransitionKey.ACTION] = convert(action.float(), ACTION)
        elif self.space.uses_galr:  # inference: encoded only if the policy reads this state (deferred.py)
            obs[OBS_STATE] = defer(lambda: convert(state, OBS_STATE), state, self.policy_width)
        else:
            obs[OBS_STATE] = convert(state, OBS_STATE)
        obs[OBS_EMBODIMENT] = ids
        self.last_ids, self.last_in_spec_order = ids, spec_order
        _ENCODERS.setdefault(self.link, weakref.WeakValueDictionary())[id(self)] = self
        new[TransitionKey.OBSERVATION] = obs
        return new

    def check_robot_state(self, state: torch.Tensor, index: int, spec_order: bool) -> None:
        """A robot's joints near its hand's limits: a reading in other units would be encoded into a state
        the policy never saw, without a word. (NaN is the state guard's, which names the entry.)"""
        q = state[..., self.wrist_dim :] if spec_order else self.maps[index].split(state, OBS_STATE)[1]
        if not q.isfinite().all():
            return
        source = f"{OBS_STATE} of the robot" + ("" if spec_order else f" (through {self.maps[index].source})")
        self.model(index).check_within_limits(q.reshape(-1, q.shape[-1]), source, LIVE_LIMIT_TOLERANCE)

    def forget_last_batch(self) -> None:
        """Its postprocessor partner no longer reads this batch's hand (one the pipeline builder encoded)."""
        self.last_ids, self.last_in_spec_order = None, False

    # --- native layout: wrist + one hand's joints ----------------------------------------------------
    def _hand_index(self, name: str) -> int:
        if name not in self.embodiments:
            raise ValueError(f"this policy was trained on {self.embodiments}; it cannot drive hand '{name}'")
        return self.embodiments.index(name)

    def _native_index(self, width: int) -> int:
        if self.hand is not None:
            return self.embodiments.index(self.hand)
        fits = [i for i, m in enumerate(self.maps) if len(m.state_names) == width]
        if len(fits) != 1:
            raise ValueError(
                f"cannot tell which hand a state of width {width} belongs to (trained on "
                f"{self.embodiments}, {len(fits)} fit); pass the hand: preprocessor_overrides="
                "{'opfa_encode_joints': {'hand': NAME}}, or add observation.embodiment to the batch"
            )
        return fits[0]

    def _from_robot(self, x: torch.Tensor, index: int, key: str, spec_order: bool) -> torch.Tensor:
        """A robot's state or action -> the policy space (body entries, then the space's hand part)."""
        self.check_width(x, index, key, spec_order)
        if spec_order:
            body, q = x[..., : self.wrist_dim], x[..., self.wrist_dim :]
        else:
            body, q = self.maps[index].split(x, key)
        return torch.cat([body, self.space.from_joints(self, index, q)], dim=-1)

    # --- merged layout: wrist + universal joints [+ cached z] ----------------------------------------
    def _from_universal(self, x: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        w, u = self.wrist_dim, self.wrist_dim + len(UNIVERSAL_JOINT_NAMES)
        if self.use_cached_latents and x.shape[-1] == u + self.latent_dim:
            return torch.cat([x[..., :w], x[..., u:]], dim=-1)
        return torch.cat([x[..., :w], self.space.from_universal(self, x[..., w:u], ids)], dim=-1)

    def get_config(self) -> dict[str, Any]:
        return {**self.config_dict(), "hand": self.hand, "use_cached_latents": self.use_cached_latents}

    def state_dict(self) -> dict[str, torch.Tensor]:
        return self.galr_state("encoder.") | self.user_hands()

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.load_galr_state(self.load_user_hands(state), "encoder.")

    def transform_features(self, features):
        width = self.policy_width
        for kind, key in ((PipelineFeatureType.OBSERVATION, OBS_STATE), (PipelineFeatureType.ACTION, ACTION)):
            if key in features.get(kind, {}):
                features[kind][key] = PolicyFeature(type=features[kind][key].type, shape=(width,))
        return features


@ProcessorStepRegistry.register("opfa_decode_joints")
@dataclass
class OpfaDecodeJointsStep(_HandSpace, ProcessorStep):
    """Policy-space actions (B, [T], body + ...) -> the attached robot's action entries, in its order and
    units (its joint map inverted); for this package's env, the wrist, then the joints in spec order."""

    hand: str | None = None
    """The attached hand, when given (not saved); else the one its preprocessor saw."""

    def __call__(self, transition):
        new = transition.copy()
        action = new[TransitionKey.ACTION]
        index = self.single_id(embodiment_ids(self.link, len(action), self.embodiments, self.hand))
        wrist, rest = action[..., : self.wrist_dim], action[..., self.wrist_dim :]
        q = self.space.to_joints(self, index, rest)
        new[TransitionKey.ACTION] = self.to_robot(index, wrist, q, _in_spec_order(self.link))
        return new

    def get_config(self) -> dict[str, Any]:
        return self.config_dict()

    def state_dict(self) -> dict[str, torch.Tensor]:
        return self.galr_state("decoder.") | self.user_hands()

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.load_galr_state(self.load_user_hands(state), "decoder.")

    def transform_features(self, features):
        return features


def embodiment_ids(link: str, batch: int, embodiments: list[str], hand: str | None = None) -> torch.Tensor:
    """Embodiment ids of a postprocessor's batch: all `hand` when it is given, else those of the batch the
    linked preprocessor saw last (a one-hand policy needs neither)."""
    if hand is not None:
        if hand not in embodiments:
            raise ValueError(
                f"hand '{hand}' is not one this policy was trained on ({', '.join(embodiments)})"
            )
        return torch.full((batch,), embodiments.index(hand), dtype=torch.long)
    live = _live_encoders(link)
    if len(live) > 1:
        raise ValueError(
            f"{len(live)} preprocessors of one policy (link '{link}') have seen observations in this "
            "process, so its postprocessors cannot tell which hand an action is for; give each postprocessor "
            "its hand: postprocessor_overrides={'opfa_unnormalize': {'hand': H}, 'opfa_decode_joints': "
            "{'hand': H}}"
        )
    if live and live[0].last_ids is not None and len(live[0].last_ids) == batch:
        return live[0].last_ids
    if len(embodiments) == 1:
        return torch.zeros(batch, dtype=torch.long)
    raise ValueError(
        "this postprocessor needs to know which hand produced the actions: run its preprocessor (same "
        f"link '{link}') on the observation first, or give it the hand"
    )


def _in_spec_order(link: str) -> bool:
    """Whether the observations the linked preprocessor saw last were in spec order (this package's env),
    so the action goes back the same way; a robot's own entries otherwise."""
    return {encoder.last_in_spec_order for encoder in _live_encoders(link)} == {True}


def _live_encoders(link: str) -> list[OpfaEncodeJointsStep]:
    live = list(_ENCODERS.get(link, {}).values())
    if len(live) > 1:  # pipelines already dropped but not yet collected do not count
        gc.collect()
        live = list(_ENCODERS.get(link, {}).values())
    return live
