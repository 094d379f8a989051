"""Small synthetic per-hand LeRobotDatasets in the layout the simulator records (wrist pose + the hand's
joints, flattened point cloud, object state), or as a robot with an arm records it (the arm's joints as
`<joint>.pos`, then the hand's). For tests, benchmarks and trying the pipeline without the simulator; the
motions are smooth random reaches and grasps, not task demonstrations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE

from lerobot_opfa.datasets.io import new_dataset
from lerobot_opfa.features import OBS_POINTCLOUD
from lerobot_opfa.hands.registry import load_hand

WRIST_NAMES = ("wrist_x", "wrist_y", "wrist_z", "wrist_yaw", "wrist_pitch", "wrist_roll")


def write_synthetic_dataset(
    root: Path | str,
    hand: str,
    episodes: int = 2,
    frames: int = 24,
    n_points: int = 64,
    fps: int = 10,
    seed: int = 0,
    joint_names: list[str] | None = None,
) -> Path:
    """Writes a dataset for `hand` under `root` (`robot_type` = the hand's name). `joint_names` overrides
    the hand's joint names in the features (to make datasets that do not match their spec). Written whole
    or not at all."""
    if min(episodes, frames, n_points) < 1:
        raise ValueError(f"need at least 1 episode, frame and point, got {episodes}, {frames}, {n_points}")
    model = load_hand(hand)
    names = [*WRIST_NAMES, *(joint_names or model.joint_names)]
    features = _features(names, n_points)
    repo_id = f"local/{Path(root).name}"
    create = dict(repo_id=repo_id, fps=fps, features=features, robot_type=hand, use_videos=False)
    with new_dataset(root, **create) as dataset:
        _write_episodes(dataset, model, episodes, frames, n_points, seed)
    return Path(root)


def write_armed_dataset(
    root: Path | str,
    arm: str,
    hand: str,
    episodes: int = 2,
    frames: int = 24,
    n_points: int = 64,
    fps: int = 10,
    seed: int = 0,
    arm_scale: float = 1.0,
) -> Path:
    """Writes a dataset of `hand` on `arm` (an `arms.spec.load_arm` reference) under `root`: state and action
    are the arm's joints (`<joint>.pos`, radians divided by `arm_scale`: 1/DEGREE records degrees), then the
    hand's; the arm sways about its home, 0.15 rad at most per joint. `robot_type` is `<arm>_<hand>`."""
    from lerobot_opfa.arms.spec import load_arm

    spec, model = load_arm(arm), load_hand(hand)
    arm_names = [f"{joint}.pos" for joint in spec.joints]
    names = [*arm_names, *model.joint_names]
    features = _features(names, n_points)
    create = dict(
        repo_id=f"local/{Path(root).name}", fps=fps, features=features, robot_type=f"{spec.name}_{hand}",
        use_videos=False,
    )  # fmt: skip
    rng = np.random.default_rng(seed)
    home = np.array(spec.home)
    lower, upper = model.lower.double().numpy(), model.upper.double().numpy()
    with new_dataset(root, **create) as dataset:
        for _ in range(episodes):
            t = np.arange(frames + 1)[:, None] / fps
            phase, rate = rng.uniform(0, 2 * np.pi, len(home)), rng.uniform(0.5, 1.5, len(home))
            joints = home + 0.15 * np.sin(rate * t + phase)
            grasp = lower + (upper - lower) * rng.uniform(0.3, 0.9, len(lower))
            closing = np.clip(t / t[-1], 0, 1)
            trajectory = np.concatenate([joints / arm_scale, lower + (grasp - lower) * closing], axis=1)
            target = rng.uniform(-0.1, 0.1, 3)
            for i in range(frames):
                dataset.add_frame({
                    OBS_STATE: trajectory[i].astype(np.float32),
                    ACTION: trajectory[i + 1].astype(np.float32),
                    OBS_POINTCLOUD: rng.normal(target, 0.03, (n_points, 3)).reshape(-1).astype(np.float32),
                    OBS_ENV_STATE: target.astype(np.float32),
                    "task": "lift the object",
                })  # fmt: skip
            dataset.save_episode()
    return Path(root)


def _features(names: list[str], n_points: int) -> dict:
    """State and action of the entries `names`, a flattened cloud of `n_points` and the object's position."""
    return {
        OBS_STATE: {"dtype": "float32", "shape": (len(names),), "names": names},
        ACTION: {"dtype": "float32", "shape": (len(names),), "names": names},
        OBS_POINTCLOUD: {"dtype": "float32", "shape": (3 * n_points,), "names": None},
        OBS_ENV_STATE: {"dtype": "float32", "shape": (3,), "names": ["object_x", "object_y", "object_z"]},
    }


def _write_episodes(dataset, model, episodes: int, frames: int, n_points: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    lower, upper = model.lower.double().numpy(), model.upper.double().numpy()
    for _ in range(episodes):
        target = np.concatenate([rng.uniform(-0.2, 0.2, 2), [rng.uniform(0.02, 0.1)]])
        s = np.linspace(0, 1, frames + 1)[:, None]
        wrist = np.zeros((frames + 1, 6))
        wrist[:, :3] = (1 - s) * np.array([0.0, 0.0, 0.3]) + s * (target + [0, 0, 0.05])
        wrist[:, 3] = rng.uniform(-0.5, 0.5) * s[:, 0]
        grasp = lower + (upper - lower) * rng.uniform(0.3, 0.9, len(lower))
        joints = lower + (grasp - lower) * np.clip(2 * s - 1, 0, 1)
        trajectory = np.concatenate([wrist, joints], axis=1).astype(np.float32)
        cloud = rng.normal(0, 0.03, (n_points, 3)) + target
        for t in range(frames):
            dataset.add_frame(
                {
                    OBS_STATE: trajectory[t],
                    ACTION: trajectory[t + 1],
                    OBS_POINTCLOUD: (cloud + rng.normal(0, 0.002, cloud.shape))
                    .reshape(-1)
                    .astype(np.float32),
                    OBS_ENV_STATE: target.astype(np.float32),
                    "task": "lift the object",
                }
            )
        dataset.save_episode()
