"""Datasets at different rates merge: each input read at the merge's rate by timestamp (joint entries and
absolute targets interpolated, other features from the nearest frame), a trajectory recorded at 30 and at
10 fps giving the same merged frames, and a recording whose timestamps cannot be resampled refused with its
episode."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE

from lerobot_opfa import cli
from lerobot_opfa.datasets.io import new_dataset, read_columns
from lerobot_opfa.datasets.layout import OPFA_META_FILE
from lerobot_opfa.datasets.merge import merge_datasets
from lerobot_opfa.datasets.resample import resampling
from lerobot_opfa.datasets.synthetic import WRIST_NAMES

NAMES = [*WRIST_NAMES, "left_jaw_joint"]


def smooth(t: np.ndarray) -> np.ndarray:
    """A umi robot's entries over time: a reach and a closing jaw, within the jaw's 0..0.044 m."""
    t = t[:, None]
    wrist = np.concatenate([0.1 * np.sin(t + [0.0, 1.0, 2.0]), 0.3 * np.cos(t + [0.5, 1.5, 2.5])], axis=1)
    return np.concatenate([wrist, 0.022 + 0.015 * np.sin(2 * t)], axis=1)


def linear(t: np.ndarray) -> np.ndarray:
    return np.concatenate([0.1 * t[:, None] * np.linspace(0.1, 0.6, 6), 0.01 + 0.02 * t[:, None]], axis=1)


def record(root: Path, fps: int, seconds: float, trajectory=smooth, episodes: int = 1) -> Path:
    """A umi dataset at `fps`: state the trajectory at each frame's time, action the trajectory 50 ms on (an
    absolute target, a function of time alone), object state the frame's time."""
    features = {
        OBS_STATE: {"dtype": "float32", "shape": (len(NAMES),), "names": NAMES},
        ACTION: {"dtype": "float32", "shape": (len(NAMES),), "names": NAMES},
        OBS_ENV_STATE: {"dtype": "float32", "shape": (1,), "names": ["time"]},
    }
    create = dict(
        repo_id=f"local/{root.name}", fps=fps, features=features, robot_type="umi", use_videos=False
    )
    with new_dataset(root, **create) as dataset:
        for _ in range(episodes):
            t = np.arange(round(seconds * fps)) / fps
            for state, action, time in zip(trajectory(t), trajectory(t + 0.05), t, strict=True):
                dataset.add_frame({OBS_STATE: state.astype(np.float32), ACTION: action.astype(np.float32),
                                   OBS_ENV_STATE: np.float32([time]), "task": "reach"})  # fmt: skip
            dataset.save_episode()
    return root


def frames_of(root: Path, episode: int) -> dict[str, np.ndarray]:
    columns = read_columns(root, [OBS_STATE, ACTION, OBS_ENV_STATE, "episode_index"])
    rows = np.flatnonzero(columns.pop("episode_index") == episode)
    return {key: values[rows].reshape(len(rows), -1) for key, values in columns.items()}


def test_a_trajectory_recorded_at_30_and_at_10_fps_merges_to_the_same_frames(tmp_path):
    fast, slow = record(tmp_path / "at30", 30, 1.0), record(tmp_path / "at10", 10, 1.0)
    out = merge_datasets([fast, slow], tmp_path / "merged")
    assert LeRobotDataset("local/merged", root=out).meta.fps == 10
    assert json.loads((out / OPFA_META_FILE).read_text())["input_fps"] == [30, 10]
    resampled, recorded = frames_of(out, 0), frames_of(out, 1)
    assert len(resampled[OBS_STATE]) == len(recorded[OBS_STATE]) == 10
    for key in (OBS_STATE, ACTION, OBS_ENV_STATE):
        assert np.abs(resampled[key] - recorded[key]).max() <= 1e-6, key
    assert np.allclose(recorded[OBS_ENV_STATE][:, 0], np.arange(10) / 10)


def test_a_rate_between_the_frames_interpolates_the_joints_and_takes_the_nearest_frame_for_the_rest(tmp_path):
    fast = record(tmp_path / "at30", 30, 1.0, trajectory=linear)
    out = merge_datasets([fast], tmp_path / "merged", fps=20)
    frames, t = frames_of(out, 0), np.arange(20) / 20
    assert len(frames[OBS_STATE]) == 20
    assert np.abs(frames[OBS_STATE][:, :7] - linear(t)).max() <= 1e-6
    assert np.abs(frames[ACTION][:, :7] - linear(t + 0.05)).max() <= 1e-6
    assert np.abs(frames[OBS_ENV_STATE][:, 0] - t).max() <= 1 / 60 + 1e-6, "the nearest recorded frame"


def _rewrite_timestamps(root: Path, change) -> None:
    for path in (root / "data").rglob("*.parquet"):
        table = pq.read_table(path)
        times = table.column("timestamp").to_numpy().copy()
        change(times)
        pq.write_table(
            table.set_column(table.schema.get_field_index("timestamp"), "timestamp", [times]), path
        )


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda t: t.__setitem__(5, t[3]), r"episode 0: timestamps go backwards at frame 5"),
        (
            lambda t: t.__setitem__(slice(12, None), t[12:] + 0.2),
            r"episode 0: a gap of 0.233 s before frame 12",
        ),
    ],
)
def test_timestamps_that_cannot_be_resampled_are_refused_with_the_episode(tmp_path, capsys, change, message):
    fast, slow = record(tmp_path / "at30", 30, 1.0), record(tmp_path / "at10", 10, 1.0)
    _rewrite_timestamps(fast, change)
    with pytest.raises(ValueError, match=message):
        merge_datasets([fast, slow], tmp_path / "merged")
    assert not (tmp_path / "merged").exists()
    merge = ["dataset", "merge", "--inputs", str(fast), str(slow), "--output", str(tmp_path / "merged")]
    assert cli.main(merge) == 2
    assert cli.main([*merge[:-2], "--output", str(tmp_path / "merged"), "--fps", "0"]) == 2
    assert "--fps: a positive rate" in capsys.readouterr().err


def test_the_resampling_of_a_recorded_rate_is_the_identity():
    times = np.arange(25) / 25
    timing = resampling(times.astype(np.float32), 25, 25, "episode 0")
    assert (timing.nearest == np.arange(25)).all()
    assert np.array_equal(timing.interpolate(np.arange(25.0)), np.arange(25.0))


@pytest.mark.parametrize("space", ["per_embodiment", "galr"])
def test_robots_recorded_at_30_and_10_fps_co_train_and_each_gets_its_own_entries_back(tmp_path, space):
    """A umi robot at 30 fps and an Inspire robot at 10 fps merge at 10 fps, train one policy, and each
    robot's action comes back in its own entries."""
    import torch
    from test_policy import batch_of, make_policy, rollout, save_galr

    from lerobot_opfa.datasets.synthetic import write_synthetic_dataset
    from lerobot_opfa.hands.registry import load_hand

    save_galr(tmp_path / "galr", ["umi", "inspire"])
    write_synthetic_dataset(tmp_path / "umi", "umi", episodes=2, frames=36, n_points=32, fps=30, seed=0)
    write_synthetic_dataset(
        tmp_path / "inspire", "inspire", episodes=2, frames=12, n_points=32, fps=10, seed=1
    )
    merge = ["dataset", "merge", "--inputs", str(tmp_path / "umi"), str(tmp_path / "inspire"), "--output",
             str(tmp_path / "merged"), "--galr", str(tmp_path / "galr")]  # fmt: skip
    assert cli.main(merge) == 0
    policy, pre, post, dataset = make_policy(tmp_path, "merged", action_space=space)
    assert dataset.meta.fps == 10 and dataset.meta.total_frames == 2 * 12 + 2 * 12
    loss, _ = policy.forward(pre(batch_of(dataset, [0, 13, 24, 40])))
    loss.backward()
    assert loss.isfinite()
    cloud = torch.randn(32 * 3) * 0.05
    for hand in ("umi", "inspire"):
        action = rollout(policy, pre, post, hand, cloud, steps=1)
        assert action.shape == (1, 6 + load_hand(hand).dof) and action.isfinite().all()
