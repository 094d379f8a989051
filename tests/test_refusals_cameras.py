"""A rig's camera mistakes are one-line errors before any work (issue 42): calibrations record their image
size and are checked for meaning, frame 0 must show the workspace, a short camera name lists the dataset's
keys, an RGB policy refuses pictures of another size or a missing camera, and clouds whose calibration was
lost to LeRobot's editing tools are refused before training."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from lerobot.configs.types import FeatureType
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils.feature_utils import dataset_to_policy_features, hw_to_dataset_features

from lerobot_opfa import cli
from lerobot_opfa.datasets.clouds import cloud_dataset
from lerobot_opfa.datasets.layout import OPFA_META_FILE
from lerobot_opfa.envs.env import OpfaSimEnv
from lerobot_opfa.envs.observation import DepthPointCloud
from lerobot_opfa.features import OBS_POINTCLOUD
from lerobot_opfa.pointclouds import MIN_VOXELS, DepthRig, DepthRigError
from lerobot_opfa.policy.configuration_opfa import OpfaConfig
from lerobot_opfa.policy.depth_step import DepthToPointCloudStep
from lerobot_opfa.policy.processor_opfa import depth_step, make_opfa_pre_post_processors

CAMERAS = ("front", "left")
KEYS = [f"observation.images.{c}_depth" for c in CAMERAS]
RGB = "observation.images.front_rgb"
POLICY = dict(device="cpu", action_space="raw", down_dims=(16, 32), horizon=8, n_action_steps=4,
              diffusion_step_embed_dim=16, n_groups=4, pointcloud_widths=(8, 16), pointcloud_feature_dim=8,
              image_feature_dim=8, cloud_points=64)  # fmt: skip


def record(root: Path, width: int, height: int, episodes: int = 1, frames: int = 6) -> tuple[Path, dict]:
    """A rig's recording at `width` x `height` (two depth cameras in uint16 millimetres, one colour camera)
    and the calibration of its depth cameras at that size, as the simulated rig writes it."""
    env = OpfaSimEnv(task="lift", hand="umi", n_points=64, depth_cameras=",".join(CAMERAS))
    depth = DepthPointCloud(env.model, 64, list(CAMERAS), width, height)
    names = [f"{n}.pos" for n in env.state_names]
    robot = {n: float for n in names} | {f"{c}_depth": (height, width, 1) for c in CAMERAS}
    features = hw_to_dataset_features(robot | {"front_rgb": (height, width, 3)}, "observation")
    features |= hw_to_dataset_features({n: float for n in names}, "action")
    dataset = LeRobotDataset.create("local/rig", 20, features=features, root=root, robot_type="umi")
    rng = np.random.default_rng(0)
    for episode in range(episodes):
        obs, _ = env.reset(seed=episode)
        for _ in range(frames):
            frame = {"observation.state": obs["agent_pos"].astype(np.float32), "task": "lift the object"}
            frame["action"] = frame["observation.state"]
            for key, image in zip(KEYS, depth.depth_images(env.data), strict=True):
                frame[key] = np.round(image * 1000).astype(np.uint16)[..., None]
            frame[RGB] = rng.integers(0, 255, (height, width, 3), dtype=np.uint8)
            dataset.add_frame(frame)
            obs, *_ = env.step(obs["agent_pos"])
        dataset.save_episode()
    dataset.finalize()
    calibration = DepthRig(dict(zip(KEYS, depth.pinhole_cameras(env.data), strict=True))).to_dict()
    depth.close()
    env.close()
    return root, calibration


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, dict]:
    return record(tmp_path_factory.mktemp("cameras") / "rig", 128, 96, episodes=2)


@pytest.fixture
def rig(recorded) -> tuple[Path, dict]:
    """128x96 frames, two episodes, and (a copy of) their calibration."""
    return recorded[0], copy.deepcopy(recorded[1])


def write(path: Path, calibration: dict) -> Path:
    path.write_text(yaml.safe_dump(calibration, sort_keys=False))
    return path


def clouds_error(source: Path, calibration: Path, output: Path, capsys) -> str:
    """`lerobot-opfa dataset clouds` refusing: its one-line message, nothing written."""
    argv = [
        "dataset",
        "clouds",
        "--input",
        str(source),
        "--output",
        str(output),
        "--cameras",
        str(calibration),
    ]
    assert cli.main([*argv, "--n-points", "64"]) != 0
    assert not output.exists()
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return err.strip().splitlines()[-1]  # progress bars of the datasets library before it


def test_frames_of_another_size_than_the_calibrations_are_refused_naming_the_camera_and_both_sizes(
    rig, tmp_path, capsys
):
    _, calibration = rig
    assert calibration["cameras"][KEYS[0]]["width"] == 128 and calibration["cameras"][KEYS[0]]["height"] == 96
    large, _ = record(tmp_path / "large", 256, 192)
    path = write(tmp_path / "cameras.yaml", calibration)
    err = clouds_error(large, path, tmp_path / "clouds", capsys)
    assert f"{large}, frame 0: camera '{KEYS[0]}' gives depth frames of 256x192" in err, err
    assert "is for 128x96" in err and str(path) in err, err
    step = DepthToPointCloudStep(rig=calibration, n_points=64)  # a checkpoint meeting a robot's frames
    frame = LeRobotDataset("local/rig", root=large)[0]
    with pytest.raises(DepthRigError, match=f"'{KEYS[0]}' gives depth frames of 256x192.*is for 128x96"):
        step.observation({k: frame[k] for k in KEYS})


def test_the_simulated_rig_writes_the_size_of_its_frames_into_its_calibration(tmp_path):
    from lerobot_opfa.rig.robot import OpfaSimRobot, OpfaSimRobotConfig

    robot = OpfaSimRobot(OpfaSimRobotConfig(hand="umi", calibration_dir=tmp_path, width=96, height=64))
    robot.connect()
    try:
        depth = robot.get_observation()["front_depth"]
        written = DepthRig.load(robot.cameras_file).cameras["observation.images.front_depth"]
    finally:
        robot.disconnect()
    assert depth.shape == (64, 96, 1) and (written.width, written.height) == (96, 64)


def test_a_calibration_without_the_image_size_says_which_keys_to_add(rig, tmp_path):
    _, calibration = rig
    for camera in calibration["cameras"].values():
        del camera["width"], camera["height"]
    path = write(tmp_path / "old.yaml", calibration)
    with pytest.raises(DepthRigError) as error:
        DepthRig.load(path)
    message = str(error.value)
    assert f"{path}: camera '{KEYS[0]}' does not say the image size" in message
    assert "add `width` and `height`" in message and "\n" not in message


def _mirrored(camera: dict) -> None:
    for row in camera["camera_to_world"][:3]:
        row[0] = -row[0]  # the camera's x axis flipped: det -1


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (_mirrored, "camera_to_world is mirrored (its rotation has determinant -1"),
        (lambda c: c.update(fx=float("nan")), "fx is nan: intrinsics are finite numbers"),
        (lambda c: c.update(fx=1.93, fy=1.93), "177 degree horizontal field of view over 128 pixels"),
        (
            lambda c: c.update(cx=300.0),
            "principal point (cx, cy) = (300, 47.5) lies outside its 128x96 image",
        ),
        (lambda c: c.update(width=0), "width and height must be positive whole pixels"),
    ],
)
def test_calibrations_are_checked_for_meaning_when_loaded(rig, tmp_path, change, message):
    _, calibration = rig
    change(calibration["cameras"][KEYS[1]])
    path = write(tmp_path / "bad.yaml", calibration)
    with pytest.raises(DepthRigError) as error:
        DepthRig.load(path)
    assert f"{path}: camera '{KEYS[1]}' " in str(error.value) and message in str(error.value), error.value
    assert "\n" not in str(error.value)
    if "field of view" in message:
        assert "focal lengths must be in pixels" in str(error.value)


def test_a_world_to_camera_pose_is_refused_on_frame_0_suggesting_its_inverse(rig, tmp_path, capsys):
    root, calibration = rig
    camera = calibration["cameras"][KEYS[0]]
    camera["camera_to_world"] = np.linalg.inv(camera["camera_to_world"]).tolist()
    path = write(tmp_path / "inverted.yaml", calibration)
    err = clouds_error(root, path, tmp_path / "clouds", capsys)
    assert f"{root}, frame 0: {path}: camera '{KEYS[0]}' puts" in err, err
    assert "looks like a world-to-camera pose; give its inverse" in err
    meta = LeRobotDatasetMetadata("local/rig", root=root)
    with pytest.raises(DepthRigError, match="world-to-camera pose; give its inverse"):  # before training
        depth_step(OpfaConfig(cameras=str(path), cloud_points=64), meta)


def test_a_frame_that_shows_a_sliver_of_the_workspace_is_refused(rig, tmp_path, capsys):
    """The old check passed any frame with one point in the box; a handful of voxels is not a scene."""
    root, calibration = rig
    calibration["workspace"] = {"low": [-0.45, -0.40, 0.004], "high": [0.45, 0.40, 0.008]}
    path = write(tmp_path / "sliver.yaml", calibration)
    err = clouds_error(root, path, tmp_path / "clouds", capsys)
    assert f"{root}, frame 0: the depth frames of {', '.join(KEYS)} put " in err, err
    assert f"occupied voxels (fewer than {MIN_VOXELS}) in the workspace" in err, err


def test_a_calibration_keyed_by_short_camera_names_lists_the_datasets_keys(rig, tmp_path, capsys):
    root, calibration = rig
    calibration["cameras"] = {k.split(".")[-1]: v for k, v in calibration["cameras"].items()}
    path = write(tmp_path / "short.yaml", calibration)
    err = clouds_error(root, path, tmp_path / "clouds", capsys)
    assert "calibrates ['front_depth', 'left_depth']" in err, err
    assert f"one of {[*KEYS, RGB]}" in err and f"'front_depth' is '{KEYS[0]}'?" in err, err


def rgb_policy(root: Path):
    from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

    meta = LeRobotDatasetMetadata("local/rig", root=root)
    config = OpfaConfig(**POLICY, visual_inputs="rgb")
    features = dataset_to_policy_features(meta.features)
    config.output_features = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    config.input_features = {k: f for k, f in features.items() if k not in config.output_features}
    torch.manual_seed(0)
    policy = OpfaPolicy(config, dataset_meta=meta).eval()
    pre, _ = make_opfa_pre_post_processors(config, dataset_meta=meta)
    return policy, pre, LeRobotDataset("local/rig", root=root)[0]


@pytest.mark.parametrize(("width", "height"), [(256, 192), (64, 48)])
def test_an_rgb_policy_refuses_pictures_of_another_size_than_it_was_trained_on(rig, width, height):
    policy, pre, frame = rgb_policy(rig[0])
    picture = torch.nn.functional.interpolate(frame[RGB][None], size=(height, width))[0]
    observation = pre({"observation.state": frame["observation.state"], RGB: picture})
    with pytest.raises(ValueError) as error:
        policy.select_action(observation)
    assert str(error.value) == (
        f"{RGB}: this policy was trained on 128x96 pictures (width x height), this one is {width}x{height}: "
        "give the camera at 128x96 (another size shows the policy another part of the view at another scale)"
    )
    assert policy.select_action(pre({"observation.state": frame["observation.state"], RGB: frame[RGB]})).shape


def test_an_rgb_policy_names_the_camera_the_observation_lacks(rig):
    policy, pre, frame = rgb_policy(rig[0])
    observation = pre(
        {"observation.state": frame["observation.state"], "observation.images.left_rgb": frame[RGB]}
    )
    with pytest.raises(ValueError) as error:
        policy.select_action(observation)
    message = str(error.value)
    assert f"the observation has no ['{RGB}'] (it has " in message, message
    assert "observation.images.left_rgb" in message and "\n" not in message


def test_clouds_whose_calibration_lerobots_editor_dropped_are_refused_before_training(rig, tmp_path, capsys):
    from lerobot.datasets.dataset_tools import delete_episodes

    root, calibration = rig
    clouds = cloud_dataset(root, tmp_path / "clouds", write(tmp_path / "c.yaml", calibration), n_points=64)
    assert json.loads((clouds / OPFA_META_FILE).read_text())["cameras"] == calibration
    edited = tmp_path / "edited"
    delete_episodes(
        LeRobotDataset("local/clouds", root=clouds), [1], output_dir=edited, repo_id="local/edited"
    )
    # LeRobot's editor rewrote meta/ without the record; what info.json may keep of it goes too (an edit of
    # a dataset made before it kept a copy, or by a tool that rewrites observation.state's feature)
    (edited / OPFA_META_FILE).unlink(missing_ok=True)
    info = json.loads((edited / "meta" / "info.json").read_text())
    info["features"]["observation.state"].pop("info", None)
    (edited / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    assert OBS_POINTCLOUD in LeRobotDatasetMetadata("local/edited", root=edited).features
    skip = ("image_feature_dim", "cloud_points", "down_dims", "pointcloud_widths")
    policy = {k: v for k, v in POLICY.items() if k not in skip}
    train = ["train", "--policy.type=opfa", *(f"--policy.{k}={v}" for k, v in policy.items()),
             "--policy.down_dims=[16,32]", "--policy.pointcloud_widths=[8,16]", "--policy.push_to_hub=false",
             "--dataset.repo_id=local/edited", f"--dataset.root={edited}", "--steps=2", "--batch_size=2",
             f"--output_dir={tmp_path / 'out'}", "--wandb.enable=false"]  # fmt: skip
    assert cli.main(train) != 0
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"{edited}: its clouds were made from the depth cameras {KEYS}" in err, err
    assert f"it lost its record ({OPFA_META_FILE}) and their calibration with it" in err
    assert not (tmp_path / "out" / "checkpoints").exists()
