"""`make_opfa_pre_post_processors`: the opfa policy's processor pipelines (found by LeRobot by name).

Preprocessor: rename -> [depth frames to a cloud] -> batch -> [batch point clouds] -> device -> joints to
policy space (z for `galr`) -> per-embodiment normalisation. Postprocessor: unnormalise -> policy space
to the robot's action entries -> CPU. The GaLR's encoder weights are saved with the preprocessor and its
decoder with the postprocessor, so a checkpoint (or a Hub repo) is self-contained.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lerobot.processor import (
    AddBatchDimensionProcessorStep,
    DeviceProcessorStep,
    NormalizerProcessorStep,
    PolicyProcessorPipeline,
    RenameObservationsProcessorStep,
    TransitionKey,
    UnnormalizerProcessorStep,
    create_transition,
)
from lerobot.processor.factory import make_policy_processor_pipelines
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa.datasets import io as dataset_io
from lerobot_opfa.datasets.clouds import recorded_rig
from lerobot_opfa.datasets.io import read_columns
from lerobot_opfa.datasets.joint_map import HANDS_SEPARATOR
from lerobot_opfa.datasets.layout import DatasetLayout
from lerobot_opfa.datasets.statistics import (
    WRIST_NOISE,
    column_statistics,
    noise_floor,
    raw_noise,
    read_statistics,
    statistics_of,
)
from lerobot_opfa.features import OBS_EMBODIMENT, column_embodiments
from lerobot_opfa.galr.model import Galr
from lerobot_opfa.hands.universal import UNIVERSAL_JOINT_NAMES
from lerobot_opfa.pointclouds import DepthRig, DepthRigError
from lerobot_opfa.policy.action_spaces import PerEmbodimentSpace, universal_mask
from lerobot_opfa.policy.configuration_opfa import OpfaConfig
from lerobot_opfa.policy.depth_step import DepthToPointCloudStep
from lerobot_opfa.policy.joint_steps import OpfaDecodeJointsStep, OpfaEncodeJointsStep, PointCloudBatchStep
from lerobot_opfa.policy.normalization import OpfaNormalizeStep, OpfaUnnormalizeStep, affine_tables
from lerobot_opfa.policy.record import resolve_config

STATS_MAX_ENCODED_FRAMES = 4096
"""Frames encoded through the GaLR for z statistics when a dataset has no usable latent cache."""


def _policy_space_tables(
    config: OpfaConfig, layout: DatasetLayout, encoder: OpfaEncodeJointsStep, root: Path
) -> dict[str, torch.Tensor]:
    """The normalisation tables of the policy's state and action: from the statistics `dataset merge`
    wrote when the policy's entries are columns of the merged dataset (and its states are the demonstrated
    ones, not `decoded_state`'s), else from the frames."""
    pooled = {key: _pooled(config, body) for key, body in _bodies(config).items()}
    fitted = _merge_statistics(config, layout, encoder, root)
    state, action, floor = fitted or _frame_statistics(config, layout, encoder, root, pooled[OBS_STATE])
    floors = {OBS_STATE: floor, ACTION: _action_floor(config, floor)}
    tables = {}
    for key, stats in ((OBS_STATE, state), (ACTION, action)):
        affine = affine_tables(stats, config.normalization, pooled[key], floors[key])
        tables |= {f"{key}.{name}": table for name, table in affine.items()}
    return tables


def _bodies(config: OpfaConfig) -> dict[str, int]:
    """Body entries of the policy's state and of its action."""
    return {OBS_STATE: len(config.wrist_names), ACTION: len(config.action_body)}


def _pooled(config: OpfaConfig, body: int) -> torch.Tensor:
    """Which entries of a policy vector with `body` body entries take statistics over all hands."""
    pooled = torch.zeros(body + sum(config.slot_widths), dtype=torch.bool)
    pooled[:body] = config.wrist_normalization == "shared"
    pooled[body:] = config.space.pools_hand_statistics
    return pooled


def _action_floor(config: OpfaConfig, state_floor: torch.Tensor) -> torch.Tensor:
    """The action's noise floor: the state's hand part (the same joints through the same encoder), after
    the physical noise of the action's own body entries."""
    bodies = _bodies(config)
    body = raw_noise(bodies[ACTION], []).expand(len(state_floor), -1)
    return torch.cat([body, state_floor[:, bodies[OBS_STATE] :]], dim=1)


Fitted = tuple[dict[str, torch.Tensor], dict[str, torch.Tensor], torch.Tensor]
"""Statistics of the policy's state and of its action (`statistics.column_statistics`), and the (E, D)
noise floor."""


def _merge_statistics(
    config: OpfaConfig, layout: DatasetLayout, encoder: OpfaEncodeJointsStep, root: Path
) -> Fitted | None:
    decoded = encoder.decoded_state and config.space.uses_galr  # the merge saw the demonstrated states
    stats = read_statistics(root) if layout.kind == "merged" and not decoded else None
    wrist, n, slots = len(config.wrist_names), len(config.embodiments), len(layout.sides)
    columns = config.space.merged_columns(wrist, layout.latent_dim, slots)
    if stats is None or columns is None:
        return None
    noise = raw_noise(wrist, list(UNIVERSAL_JOINT_NAMES)).expand(n, -1)
    hand = [noise[:, wrist:] * universal_mask(config.embodiment_joints)]
    if layout.latent_dim:  # the merge that cached them wrote their noise floor
        hand.append(stats["latent_noise_floor"].expand(n, -1))
    floor = torch.cat([noise[:, :wrist], *hand * slots], dim=1)[:, columns]
    state, action = (
        {
            name: value if name == "count" else value[..., columns]
            for name, value in statistics_of(stats, key).items()
        }
        for key in (OBS_STATE, ACTION)
    )
    return state, action, floor


def _frame_statistics(
    config: OpfaConfig, layout: DatasetLayout, encoder: OpfaEncodeJointsStep, root: Path, pooled: torch.Tensor
) -> Fitted:
    merged = layout.kind == "merged"
    columns = [OBS_STATE, ACTION] + ([OBS_EMBODIMENT] if merged else ["episode_index"])
    frames = {k: torch.tensor(v, dtype=torch.float32) for k, v in read_columns(root, columns).items()}
    if not merged:
        episodes = frames.pop("episode_index")
        _check_robot_frames(config, layout, encoder, frames, root)
        layout.joint_maps[0].check_senses(frames[OBS_STATE], frames[ACTION], episodes)
    n = len(frames[OBS_STATE])
    subsample = config.space.uses_galr and not encoder.use_cached_latents and merged
    if subsample and n > STATS_MAX_ENCODED_FRAMES:
        keep = torch.randperm(n, generator=torch.Generator().manual_seed(0))[:STATS_MAX_ENCODED_FRAMES]
        frames = {k: v[keep] for k, v in frames.items()}

    def encode(rows: torch.Tensor, ids: torch.Tensor | None, action: torch.Tensor | None = None):
        observation = {OBS_STATE: rows} | ({OBS_EMBODIMENT: ids} if merged else {})
        return encoder(create_transition(observation=observation, action=action))

    out = encode(frames[OBS_STATE], frames[OBS_EMBODIMENT].long() if merged else None, frames[ACTION])
    ids = out[TransitionKey.OBSERVATION][OBS_EMBODIMENT]
    wrist = len(config.wrist_names)
    if merged:  # the joints only (cached z would not move with them)
        slots = len(layout.sides)
        raw = frames[OBS_STATE][:, PerEmbodimentSpace().merged_columns(wrist, layout.latent_dim, slots)]
        noise = raw_noise(wrist, list(UNIVERSAL_JOINT_NAMES) * slots)
    else:  # the robot's entries, each with its joint's noise in the robot's units
        raw = frames[OBS_STATE]
        joints = [raw_noise(0, encoder.model(index).spec.universal_names) for index in layout.robots[0]]
        noise = layout.joint_maps[0].entry_noise(OBS_STATE, WRIST_NOISE, joints).float()
    n_embodiments = len(config.embodiments)
    state_ids, action_ids = (column_embodiments(ids, config.blocks(key)) for key in (OBS_STATE, ACTION))
    frame_ids = frames[OBS_EMBODIMENT].long() if merged else None
    floor = noise_floor(
        lambda rows, kept: encode(rows, None if frame_ids is None else frame_ids[kept])[
            TransitionKey.OBSERVATION
        ][OBS_STATE],
        raw,
        out[TransitionKey.OBSERVATION][OBS_STATE],
        state_ids,
        noise,
        n_embodiments,
        pooled,
    )
    state = column_statistics(out[TransitionKey.OBSERVATION][OBS_STATE], state_ids, n_embodiments)
    return state, column_statistics(out[TransitionKey.ACTION], action_ids, n_embodiments), floor


def _check_robot_frames(
    config: OpfaConfig, layout: DatasetLayout, encoder: OpfaEncodeJointsStep, frames: dict, root: Path
) -> None:
    """A robot's recorded joints, read through its map, are within its hands' limits and span them as a
    joint does (`JointMap.check_spans`); for `galr`, every frame's z is encoded once, not each sample's
    window at every step."""
    joint_map, robot, joints = layout.joint_maps[0], layout.robots[0], {}
    for key in (OBS_STATE, ACTION):
        if joint_map.armed:
            joint_map.check_arms(frames[key], key, f"{root} ({key}, through {joint_map.source})")
        _, qs = joint_map.split(frames[key], key)
        for index, slot, q in zip(robot, joint_map.slots, qs, strict=True):
            side = f", {slot.side} hand" if slot.side else ""
            encoder.model(index).check_within_limits(q, f"{root} ({key}, through {joint_map.source}{side})")
            joints.setdefault(index, []).append(q)
        limits = [(encoder.model(index).lower, encoder.model(index).upper) for index in robot]
        joint_map.check_spans(frames[key], key, limits)
    if config.space.uses_galr:
        for index, rows in joints.items():
            encoder.cache_latents(index, torch.cat(rows).to(config.device or "cpu"))


def depth_step(config: OpfaConfig, meta: Any) -> DepthToPointCloudStep | None:
    """The depth step of `config.cameras`, judged on the dataset's first frame (`DepthRig.check_frame`: a
    pose, unit or workspace that does not show the workspace is an error now, not a training run on clouds
    of the wrong place); or, for a dataset whose clouds `dataset clouds` made, the step they were made with,
    so that a robot's depth frames take the same path. Clouds made from depth whose calibration is gone
    (LeRobot's own editing tools rewrite meta/) are refused: their policy could not take a robot's frames."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if not config.cameras:
        if (recorded := recorded_rig(meta)) is None:
            return None
        return DepthToPointCloudStep(rig=recorded.to_dict(), n_points=config.n_points)
    rig = DepthRig.load(config.cameras)
    rig.check_keys(meta.features, str(meta.root))
    try:
        rig.check_frame(LeRobotDataset(meta.repo_id, root=meta.root, episodes=[0])[0])
    except DepthRigError as err:
        raise DepthRigError(f"{meta.root}, frame 0: {err}") from None
    return DepthToPointCloudStep(rig=rig.to_dict(), n_points=config.cloud_points)


def check_trainable_frames(config: OpfaConfig, layout: DatasetLayout, root: Path) -> None:
    """Every hand keeps frames to train on once LeRobot's sampler drops the last `drop_n_last_frames` of
    each episode; a hand it would skip entirely would be listed by the policy without being learned."""
    columns = ["episode_index"] + ([OBS_EMBODIMENT] if layout.kind == "merged" else [])
    frames = dataset_io.read_columns(root, columns)  # two bookkeeping columns, not the frames' values
    episodes, first, lengths = np.unique(frames["episode_index"], return_index=True, return_counts=True)
    slots = len(layout.sides)
    ids = (
        frames[OBS_EMBODIMENT].reshape(len(frames["episode_index"]), slots)[first]
        if layout.kind == "merged"
        else None
    )
    drop = config.drop_n_last_frames
    for slot_ids in layout.robots:
        hand = HANDS_SEPARATOR.join(layout.embodiments[e] for e in slot_ids)
        mine = lengths if ids is None else lengths[(ids == slot_ids).all(axis=1)]
        if not len(mine):
            raise ValueError(
                f"{root} has no episode of hand '{hand}', though its observation.embodiment lists it: they "
                "were deleted after the merge (lerobot-edit-dataset delete_episodes); merge the inputs again "
                "without that hand, or with its episodes"
            )
        if np.maximum(mine - drop, 0).sum() == 0:
            raise ValueError(
                f"hand '{hand}' has no frame to train on: its {len(mine)} episode(s) are at most "
                f"{mine.max(initial=0)} frames long, and training skips the last {drop} of each (horizon "
                f"{config.horizon} - n_action_steps {config.n_action_steps} - n_obs_steps "
                f"{config.n_obs_steps} + 1); record longer episodes or lower --policy.horizon"
            )


@dataclasses.dataclass
class PolicySpaceSteps:
    """The steps between a robot's entries and the normalised policy space, built from a dataset: `opfa`
    runs them in its pipelines, and a stock policy gets the same ones (`policy.stock`)."""

    encode: OpfaEncodeJointsStep
    normalize: OpfaNormalizeStep
    unnormalize: OpfaUnnormalizeStep
    decode: OpfaDecodeJointsStep


def hand_entry_names(config: OpfaConfig, layout: DatasetLayout, encode: OpfaEncodeJointsStep) -> list[str]:
    """The names of the policy's entries after the body: each hand slot's (`left.z0`, ... for two)."""
    names = []
    for index, side in zip(layout.robots[0], layout.sides, strict=True):
        prefix = f"{side}." if side is not None and len(layout.sides) > 1 else ""
        names += [prefix + name for name in config.space.hand_names(encode, index)]
    return names


def policy_space_steps(
    config: OpfaConfig, meta: Any, layout: DatasetLayout, galr: Galr | None
) -> PolicySpaceSteps:
    """The joint map, the GaLR encode, the per-embodiment normalisation (fitted on `meta`'s frames) and
    their inverses, for the config `resolve_config` filled from `meta`; the postprocessor's steps are
    paired with the encode step (`joint_steps`)."""
    cached = galr is not None and layout.latent_dim > 0  # policy_galr checked that this GaLR made them
    encode = OpfaEncodeJointsStep(
        action_space=config.action_space,
        embodiments=list(config.embodiments),
        hand_refs=list(layout.hand_refs),
        embodiment_joints=[list(joints) for joints in config.embodiment_joints],
        wrist_dim=len(config.wrist_names),
        action_wrist_dim=None if config.action_body_names is None else len(config.action_body_names),
        galr_config=dataclasses.asdict(galr.config) if galr is not None else None,
        joint_maps=[m.to_dict() for m in layout.joint_maps],
        robots=[list(robot) for robot in layout.robots],
        galr=galr,
        use_cached_latents=cached,
        record_for_decode=True,
        decoded_state=config.decoded_state,
        fps=int(meta.fps),
    )
    tables = _policy_space_tables(config, layout, encode, Path(meta.root))
    normalize = OpfaNormalizeStep(
        tables=tables,
        slot_widths=config.slot_widths,
        names=[*config.wrist_names, *hand_entry_names(config, layout, encode)],
        embodiments=list(config.embodiments),
    )
    unnormalize = OpfaUnnormalizeStep(
        keys=[ACTION],
        tables={k: v for k, v in tables.items() if k.startswith(ACTION)},
        slot_widths=config.slot_widths,
        embodiments=list(config.embodiments),
        relative_step=encode,
    )
    return PolicySpaceSteps(encode, normalize, unnormalize, OpfaDecodeJointsStep(relative_step=encode))


def make_opfa_pre_post_processors(
    config: OpfaConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
    dataset_meta: Any | None = None,
) -> tuple[PolicyProcessorPipeline, PolicyProcessorPipeline]:
    """Fresh pipelines for training on `dataset_meta`'s dataset (lerobot-train passes it through the
    config as `_runtime_dataset_meta`). Per-embodiment statistics are computed from the dataset's frames,
    so `dataset_stats` (pooled over hands) is not used."""
    meta = dataset_meta if dataset_meta is not None else getattr(config, "_runtime_dataset_meta", None)
    if meta is None:
        raise ValueError("opfa processors are built from the training dataset: pass dataset_meta")
    config, layout, galr = resolve_config(config, meta)
    if config.cameras:
        config.validate_features()  # the depth features become the cloud the depth step makes
    check_trainable_frames(config, layout, Path(meta.root))
    depth, clouds = [], []
    if config.uses_pointcloud:
        depth = [step for step in [depth_step(config, meta)] if step is not None]
        clouds = [PointCloudBatchStep(n_points=config.n_points)]
    steps = policy_space_steps(config, meta, layout, galr)
    return make_policy_processor_pipelines(
        input_steps=[
            RenameObservationsProcessorStep(rename_map={}),
            *depth,
            AddBatchDimensionProcessorStep(),
            *clouds,
            DeviceProcessorStep(device=config.device),
            steps.encode,
            steps.normalize,
            NormalizerProcessorStep(features={}, norm_map=config.normalization_mapping),
        ],
        output_steps=[
            UnnormalizerProcessorStep(features={}, norm_map=config.normalization_mapping),
            steps.unnormalize,
            steps.decode,
            DeviceProcessorStep(device="cpu"),
        ],
    )
