"""Depth maps to point clouds: a dataset recorded with depth cameras (LeRobot's own writer, its depth
encoding) trains `opfa` through the depth step, whose clouds are the simulator's from the same images."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils.feature_utils import hw_to_dataset_features
from scipy.spatial import cKDTree
from subprocesses import run_lerobot_here

from lerobot_opfa import cli
from lerobot_opfa.envs.env import OpfaSimEnv
from lerobot_opfa.features import OBS_POINTCLOUD
from lerobot_opfa.pointclouds import VOXEL, DepthRig, DepthRigError
from lerobot_opfa.policy.depth_step import DepthToPointCloudStep

ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
CAMERAS = ("front", "left")
KEYS = [f"observation.images.{c}_depth" for c in CAMERAS]
N_POINTS = 2048


def record(
    root: Path, frames: int = 6, episodes: int = 2, cloud_points: int = N_POINTS, hand: str = "umi"
) -> tuple[Path, list]:
    """A rig's episodes as `lerobot-record` writes them: joints under `<name>.pos`, two depth cameras
    (H, W, 1) in millimetres as uint16 (a RealSense's `read_depth`), encoded as LeRobot's depth video; the
    calibration file beside it. Returns the calibration and, per frame, the simulator's own cloud."""
    env = OpfaSimEnv(task="lift", hand=hand, n_points=cloud_points, depth_cameras=",".join(CAMERAS))
    names = [f"{n}.pos" for n in env.state_names]
    robot = {n: float for n in names} | {f"{c}_depth": (96, 128, 1) for c in CAMERAS}
    features = hw_to_dataset_features(robot, "observation") | hw_to_dataset_features(
        {n: float for n in names}, "action"
    )
    fps = env.metadata["render_fps"]
    dataset = LeRobotDataset.create("local/rig", fps, features=features, root=root / "rig", robot_type=hand)
    sim_clouds = []
    for episode in range(episodes):
        obs, _ = env.reset(seed=episode)
        for _ in range(frames):
            sim_clouds.append(obs["pointcloud"].reshape(-1, 3))
            depths = env.views.sampler.depth_images(
                env.data
            )  # the images the simulator's cloud was made from
            frame = {"observation.state": obs["agent_pos"].astype(np.float32), "task": "lift the object"}
            frame["action"] = frame["observation.state"]
            for key, depth in zip(KEYS, depths, strict=True):
                frame[key] = np.round(depth * 1000).astype(np.uint16)[..., None]
            dataset.add_frame(frame)
            obs, *_ = env.step(obs["agent_pos"])
        dataset.save_episode()
    dataset.finalize()
    cameras = dict(zip(KEYS, env.views.sampler.pinhole_cameras(env.data), strict=True))
    calibration = root / "cameras.yaml"
    calibration.write_text(yaml.safe_dump(DepthRig(cameras).to_dict()))
    env.close()
    return calibration, sim_clouds


@pytest.fixture(scope="module")
def rig(tmp_path_factory) -> tuple[Path, Path, list]:
    root = tmp_path_factory.mktemp("depth")
    calibration, sim_clouds = record(root)
    return root / "rig", calibration, sim_clouds


def test_the_depth_step_gives_the_simulators_clouds_from_a_lerobot_depth_dataset(rig):
    root, calibration, sim_clouds = rig
    dataset = LeRobotDataset("local/rig", root=root)
    assert all(dataset.meta.features[k]["info"]["is_depth_map"] for k in KEYS)
    step = DepthToPointCloudStep(rig=DepthRig.load(calibration).to_dict(), n_points=N_POINTS)
    for i in (0, 5, 9):
        frame = dataset[i]
        cloud = step.observation({k: frame[k] for k in KEYS})[OBS_POINTCLOUD].reshape(-1, 3).numpy()
        sim = sim_clouds[i]
        to_sim, to_step = cKDTree(sim).query(cloud)[0], cKDTree(cloud).query(sim)[0]
        # both draw from one voxel per occupied 4 mm cell: each point within a voxel's diagonal of the other
        for distances in (to_sim, to_step):
            assert np.quantile(distances, 0.99) < np.sqrt(3) * VOXEL, np.quantile(distances, [0.5, 0.99, 1])
            assert distances.mean() < VOXEL / 2


def test_the_step_takes_batches_histories_and_a_robots_frames(rig):
    root, calibration, _ = rig
    step = DepthToPointCloudStep(rig=DepthRig.load(calibration).to_dict(), n_points=64)
    frame = LeRobotDataset("local/rig", root=root)[0]
    history = {
        k: torch.stack([frame[k], frame[k]])[None].repeat(3, 1, 1, 1, 1) for k in KEYS
    }  # (B, T, 1, H, W)
    assert step.observation(dict(history))[OBS_POINTCLOUD].shape == (3, 2, 64 * 3)
    robot = {k: frame[k][0].numpy().round().astype(np.uint16)[..., None] for k in KEYS}  # (H, W, 1), mm
    observation = step.observation({**robot, "observation.state": torch.zeros(7)})
    assert observation[OBS_POINTCLOUD].shape == (64 * 3,) and not any(k in observation for k in KEYS)
    with pytest.raises(ValueError, match=r"no depth frames \['observation.images.left_depth'\]"):
        step.observation({KEYS[0]: frame[KEYS[0]]})


def test_calibration_errors_are_one_line(rig, tmp_path):
    _, calibration, _ = rig
    good = yaml.safe_load(calibration.read_text())
    camera = good["cameras"][KEYS[0]]
    cases = [
        ({**good, "depth_unit": "cm"}, "depth_unit 'cm' is not one of"),
        ({"cameras": {KEYS[0]: {k: v for k, v in camera.items() if k != "fx"}}}, "needs exactly"),
        ({"cameras": {KEYS[0]: {**camera, "camera_to_world": [[2, 0, 0, 0]] * 4}}}, "rigid 4x4 pose"),
        ({"cameras": {KEYS[0]: {**camera, "fy": -3}}}, "positive fx and fy"),
        ({**good, "workspace": {"low": [0, 0, 1], "high": [1, 1, 0]}}, "low < high"),
        ({**good, "rig": 1}, "unknown keys \\['rig'\\]"),
    ]
    for i, (raw, message) in enumerate(cases):
        path = tmp_path / f"c{i}.yaml"
        path.write_text(yaml.safe_dump(raw))
        with pytest.raises(DepthRigError, match=message) as error:
            DepthRig.load(path)
        assert str(path) in str(error.value) and "\n" not in str(error.value)


def _train_flags(root: Path, out: Path, *flags: str) -> list[str]:
    policy = {"type": "opfa", "action_space": "raw", "device": "cpu", "push_to_hub": "false", "horizon": 8,
              "down_dims": "[16,32]", "n_action_steps": 4, "pointcloud_widths": "[8,16]",
              "pointcloud_feature_dim": 8, "cloud_points": 64}  # fmt: skip
    return [*(f"--policy.{k}={v}" for k, v in policy.items()), "--dataset.repo_id=local/rig",
            f"--dataset.root={root}", "--steps=2", "--batch_size=2", "--num_workers=0", "--save_freq=2",
            f"--output_dir={out}", "--wandb.enable=false", *flags]  # fmt: skip


def _train(monkeypatch, root: Path, out: Path, *flags: str) -> Path:
    """LeRobot's `lerobot-train` (its entry point, in this process); the checkpoint it saved."""
    run_lerobot_here("lerobot_train", _train_flags(root, out, *flags), monkeypatch)
    return out / "checkpoints" / "last" / "pretrained_model"


def _refused(capsys, root: Path, out: Path, *flags: str) -> str:
    """The one line `lerobot-opfa train` (LeRobot's training loop, in this process) refuses with."""
    assert cli.main(["train", *_train_flags(root, out, *flags)]) != 0
    return capsys.readouterr().err.strip().splitlines()[-1]


def test_lerobot_train_on_depth_then_the_checkpoint_acts_on_a_robots_depth_frames(rig, tmp_path, monkeypatch):
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

    root, calibration, _ = rig
    checkpoint = _train(monkeypatch, root, tmp_path / "out", f"--policy.cameras={calibration}")
    calibration.rename(calibration.with_suffix(".moved"))  # the checkpoint carries the calibration
    try:
        policy = OpfaPolicy.from_pretrained(checkpoint)
        pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
        frame = LeRobotDataset("local/rig", root=root)[4]
        # what lerobot-rollout hands the preprocessor: (1, 1, H, W) uint16 millimetres
        observation = {k: torch.from_numpy(frame[k].numpy().round().astype(np.uint16))[None] for k in KEYS}
        observation["observation.state"] = frame["observation.state"][None]
        with torch.no_grad():
            action = post(policy.select_action(pre(observation)))
        assert action.shape == (1, 7) and action.isfinite().all()
    finally:
        calibration.with_suffix(".moved").rename(calibration)


def test_depth_without_calibration_and_a_pose_that_sees_nothing_are_errors_before_training(
    rig, tmp_path, capsys
):
    root, calibration, _ = rig
    last = _refused(capsys, root, tmp_path / "a")
    assert f"give the depth cameras {KEYS} their calibration: --policy.cameras=FILE" in last, last
    raw = yaml.safe_load(calibration.read_text())
    for camera in raw["cameras"].values():
        camera["camera_to_world"][2][3] += 5.0  # five metres up: every point above the workspace
    blind = tmp_path / "blind.yaml"
    blind.write_text(yaml.safe_dump(raw))
    last = _refused(capsys, root, tmp_path / "b", f"--policy.cameras={blind}")
    assert not (tmp_path / "b" / "checkpoints").exists()
    assert f"{root}, frame 0: the depth frames of" in last and "put no point in the workspace" in last, last


def test_depth_datasets_of_two_hands_merge_with_their_frames_and_train_one_policy(rig, tmp_path, monkeypatch):
    from lerobot_opfa.datasets.merge import merge_datasets

    root, calibration, _ = rig
    inspire, _ = record(tmp_path / "inspire_rig", hand="inspire")
    merged = merge_datasets([root, inspire.parent / "rig"], tmp_path / "merged", galr_path="default")
    frames = LeRobotDataset("local/merged", root=merged)
    assert all(frames.meta.features[k]["info"]["is_depth_map"] for k in KEYS)
    source = LeRobotDataset("local/rig", root=root)
    assert torch.equal(frames[3][KEYS[1]], source[3][KEYS[1]])  # millimetres, as recorded
    checkpoint = _train(
        monkeypatch, merged, tmp_path / "out", f"--policy.cameras={calibration}", "--policy.action_space=galr"
    )
    assert (checkpoint / "model.safetensors").is_file()


def test_clouds_made_once_train_in_memory_and_the_checkpoint_still_takes_depth_frames(rig, tmp_path, capsys):
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

    root, calibration, _ = rig
    clouds = tmp_path / "clouds"
    argv = ["dataset", "clouds", "--input", str(root), "--output", str(clouds), "--cameras", str(calibration)]
    assert cli.main([*argv, "--n-points", "64"]) == 0
    converted = LeRobotDataset("local/clouds", root=clouds)
    assert not any(k in converted.meta.features for k in KEYS)
    step = DepthToPointCloudStep(rig=DepthRig.load(calibration).to_dict(), n_points=64)
    frame = LeRobotDataset("local/rig", root=root)[0]
    made = step.observation({k: frame[k] for k in KEYS})[OBS_POINTCLOUD]
    assert torch.equal(converted[0][OBS_POINTCLOUD], made)  # the step's own cloud, frame for frame
    policy = {"type": "opfa", "action_space": "raw", "device": "cpu", "push_to_hub": "false", "horizon": 8,
              "down_dims": "[16,32]", "n_action_steps": 4, "pointcloud_widths": "[8,16]",
              "pointcloud_feature_dim": 8}  # fmt: skip
    train = ["train", *(f"--policy.{k}={v}" for k, v in policy.items()), "--dataset.repo_id=local/clouds",
             f"--dataset.root={clouds}", "--steps=2", "--batch_size=2", "--save_freq=2",
             f"--output_dir={tmp_path / 'out'}", "--wandb.enable=false"]  # fmt: skip
    assert cli.main(train) == 0, capsys.readouterr().err[-2000:]
    checkpoint = tmp_path / "out" / "checkpoints" / "last" / "pretrained_model"
    loaded = OpfaPolicy.from_pretrained(checkpoint)
    pre, post = make_pre_post_processors(loaded.config, pretrained_path=str(checkpoint))
    observation = {k: torch.from_numpy(frame[k].numpy().round().astype(np.uint16))[None] for k in KEYS}
    observation["observation.state"] = frame["observation.state"][None]
    with torch.no_grad():
        action = post(loaded.select_action(pre(observation)))
    assert action.shape == (1, 7) and action.isfinite().all()


def test_clouds_of_two_hands_merge_with_the_calibration_they_were_made_with(rig, tmp_path, caplog):
    from lerobot_opfa.datasets.clouds import cloud_dataset, recorded_cameras
    from lerobot_opfa.datasets.merge import merge_datasets

    root, calibration, _ = rig
    inspire, _ = record(tmp_path / "inspire_rig", hand="inspire", episodes=1)
    clouds = [cloud_dataset(d, tmp_path / f"clouds_{i}", calibration, n_points=64)
              for i, d in enumerate([root, inspire.parent / "rig"])]  # fmt: skip
    merged = merge_datasets(clouds, tmp_path / "merged", galr_path="default")
    assert recorded_cameras(merged) == DepthRig.load(calibration).to_dict()
    moved = DepthRig.load(calibration).to_dict()
    moved["workspace"]["high"][2] += 0.1
    (tmp_path / "moved.yaml").write_text(yaml.safe_dump(moved))
    elsewhere = cloud_dataset(inspire.parent / "rig", tmp_path / "clouds_moved", tmp_path / "moved.yaml", 64)
    mixed = merge_datasets([clouds[0], elsewhere], tmp_path / "mixed", galr_path="default")
    assert recorded_cameras(mixed) is None
    assert "different camera calibrations" in caplog.text
