"""Scripted demonstrations recorded as a LeRobotDataset (v3), one (task, hand) per dataset, with the
episodes spread over the chosen regions. Only successful episodes are kept. A two-hand task takes its hands
as one name, left first (`inspire+xhand`), and its dataset records the joint map of its entries."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE
from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from lerobot_opfa.datasets.io import new_dataset
from lerobot_opfa.datasets.joint_map import HANDS_SEPARATOR
from lerobot_opfa.datasets.layout import OPFA_META_FILE, hand_entry
from lerobot_opfa.envs import DEFAULT_FPS
from lerobot_opfa.envs.env import OpfaSimEnv
from lerobot_opfa.envs.experts import ScriptedExpert
from lerobot_opfa.envs.regions import parse_regions
from lerobot_opfa.envs.tasks import ENV_STATE_DIM
from lerobot_opfa.features import OBS_POINTCLOUD
from lerobot_opfa.hands.registry import hand_ref

logger = logging.getLogger(__name__)

MAX_ATTEMPTS_PER_EPISODE = 3
HOLD_STEPS = 8
"""Frames recorded after an episode first succeeds, the expert holding its last target (the press, the
lifted can). Without them no training chunk starts in the last approach: LeRobot's sampler skips an
episode's last `drop_n_last_frames` frames as chunk starts, so a policy that reaches the end of the
approach a little late has never seen what to do there and starts the approach over."""
META_FILE = "opfa_demos.json"  # in the dataset's meta/: task, hand, regions and seed of every episode


def dataset_features(env: OpfaSimEnv) -> dict:
    """LeRobot features of a demo dataset: state and action named after the wrist and the hand's joints (or
    the entries of the env's `ee_delta` control)."""
    state, action = env.state_names, env.action_names
    return {
        OBS_STATE: {"dtype": "float32", "shape": (len(state),), "names": state},
        ACTION: {"dtype": "float32", "shape": (len(action),), "names": action},
        OBS_POINTCLOUD: {"dtype": "float32", "shape": (3 * env.n_points,), "names": None},
        OBS_ENV_STATE: {"dtype": "float32", "shape": (ENV_STATE_DIM,), "names": None},
    }


def expert_episode(
    env: OpfaSimEnv, seed: int, region: str | None = None, hold: int = HOLD_STEPS
) -> tuple[list[dict], bool]:
    """Run the scripted expert for one seeded episode; returns its frames (up to its first success, then
    `hold` more) and whether it succeeded."""
    obs, _ = env.reset(seed=seed, options={"region": region} if region else None)
    expert = ScriptedExpert(env, np.random.default_rng(seed))
    frames, readings, success, held = [], [], False, 0
    steps = env.task.episode_steps
    for step in range(steps + hold):
        if step == steps and not success:
            break
        action = env.command(expert.act())
        frames.append(
            {
                OBS_STATE: obs["agent_pos"].astype(np.float32),
                ACTION: action.astype(np.float32),
                OBS_POINTCLOUD: obs["pointcloud"].astype(np.float32),
                OBS_ENV_STATE: obs["environment_state"].astype(np.float32),
                "task": env.task_description,
            }
        )
        obs, _, _, _, info = env.step(action)
        readings.append(env.hand_readings())
        success = success or bool(info["is_success"])
        if success:
            if held == hold:
                break
            held += 1
    if success:  # training refuses a hand read past its limits: say so now, not after the recording
        for side, hand in env.hand_models.items():
            hand.check_within_limits(
                torch.from_numpy(np.stack([reading[side] for reading in readings])),
                f"the expert's episode (seed {seed}" + (f", {side} hand)" if side else ")"),
                hint="contact pushed the simulated joint past its stop; check the spec's limits and grasp "
                "pose",
            )
    return frames, success


def record_demos(
    task: str,
    hand: str,
    episodes: int,
    output_dir: Path,
    regions: str = "all",
    seed: int = 0,
    repo_id: str | None = None,
    n_points: int = 1024,
    pointcloud_source: str = "depth",
    depth_cameras: str = "front",
    overwrite: bool = False,
    control: str = "joints",
    arm: str | None = None,
    fps: int = DEFAULT_FPS,
) -> LeRobotDatasetMetadata:
    """Record `episodes` successful expert episodes, cycling through the regions, into `output_dir`, which
    appears whole or not at all (and only with `overwrite` replaces an existing folder). No successful
    episode at all is an error."""
    region_names = parse_regions(regions)
    env = OpfaSimEnv(
        task, hand, region_names, obs_type="pointcloud_state", pointcloud_source=pointcloud_source,
        n_points=n_points, depth_cameras=depth_cameras, control=control, arm=arm, fps=fps,
    )  # fmt: skip
    try:
        create = dict(
            repo_id=repo_id or _repo_id(env),
            fps=env.metadata["render_fps"],
            features=dataset_features(env),
            robot_type=env.robot_type,
            use_videos=False,
        )
        with new_dataset(output_dir, overwrite, **create) as dataset:
            _record(env, episodes, dataset, region_names, seed)
    finally:
        env.close()
    return LeRobotDatasetMetadata(repo_id or _repo_id(env), root=output_dir)


def failure_reason(env: OpfaSimEnv, env_states: np.ndarray) -> str:
    """Why a failed expert episode (its object states, one row a step) failed, in one line naming the
    phase."""
    model, hand = env.model, env.scene.hand_geoms
    if not (model.geom_contype[hand] | model.geom_conaffinity[hand]).any():
        return (
            "reach: the hand has no collision geometry and passes through objects; give its model collision "
            "shapes (URDF <collision>, MJCF geoms with contype or conaffinity)"
        )
    return env.task.failure(env_states)


def _repo_id(env: OpfaSimEnv) -> str:
    return f"local/opfa_{env.task.name}_{env.robot_type.replace(HANDS_SEPARATOR, '_')}"


def _record(env: OpfaSimEnv, episodes: int, dataset, region_names: list[str], seed: int) -> None:
    task, root = env.task.name, dataset.root
    records, attempts, reason = [], 0, ""
    # a failed episode's line goes above the progress bar, not after it on the same line
    with logging_redirect_tqdm(), tqdm(total=episodes, desc=f"demos {task}/{env.hand_name}") as bar:
        while len(records) < episodes and attempts < MAX_ATTEMPTS_PER_EPISODE * episodes:
            region = region_names[len(records) % len(region_names)]
            episode_seed = seed + attempts
            attempts += 1
            frames, success = expert_episode(env, episode_seed, region)
            if not success:
                if frames:
                    reason = failure_reason(env, np.stack([frame[OBS_ENV_STATE] for frame in frames]))
                    logger.warning("expert failed (seed %d, region %s): %s", episode_seed, region, reason)
                continue
            for frame in frames:
                dataset.add_frame(frame)
            dataset.save_episode()
            records.append(
                {"episode_index": len(records), "region": region, "seed": episode_seed, "length": len(frames)}
            )
            bar.update(1)
    if not records:
        raise ValueError(
            f"no expert episode of {task} with '{env.hand_name}' succeeded in {attempts} attempts"
            f"{f' (the last: {reason})' if reason else ''}; "
            f"watch one with `lerobot-opfa sim show --task {task} --hand {_hand_path(env)} --out "
            "scene.png --video expert.mp4` and check the spec's grasp pose"
        )
    dataset.finalize()
    if len(records) < episodes:
        logger.warning("only %d of %d episodes succeeded in %d attempts", len(records), episodes, attempts)
    meta = {
        "task": task,
        "hand": env.hand_name,
        "arm": None if env.arm_joints is None else env.arm_joints.ref,
        "regions": region_names,
        "seed": seed,
        "attempts": attempts,
        "hold_steps": HOLD_STEPS,
        "pointcloud_source": env.pointcloud_source,
        "depth_cameras": list(env.depth_cameras) if env.pointcloud_source == "depth" else [],
    }
    (Path(root) / "meta" / META_FILE).write_text(json.dumps({**meta, "episodes": records}, indent=2))
    specs = [hand.spec for hand in env.hand_models.values()]
    users = {spec.name: hand_entry(spec) for spec in specs if hand_ref(spec) != spec.name}
    record = {"hands": users} if users else {}  # a user's hand: later commands find it from the dataset
    if len(env.hand_models) > 1 or env.arm_joints is not None:
        record["joint_map"] = env.joint_map.to_dict()  # which entries are which side's hand, or the arm's
    if record:
        (Path(root) / OPFA_META_FILE).write_text(json.dumps(record, indent=2))


def _hand_path(env: OpfaSimEnv) -> str:
    return HANDS_SEPARATOR.join(str(hand.spec.path) for hand in env.hand_models.values())
