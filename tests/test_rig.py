"""The benchmark as LeRobot hardware: `lerobot-record` records the scripted expert on the `opfa_sim` rig
with LeRobot's own recorder, `lerobot-train` trains `opfa` from its depth frames and `lerobot-rollout`
deploys the checkpoint on the rig, as on a real robot."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from subprocesses import run_command, run_lerobot_here

from lerobot_opfa import cli
from lerobot_opfa.envs.config import OpfaEnvConfig
from lerobot_opfa.experiments.failures import image_goal_scatter, object_following

ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1", "MUJOCO_GL": "egl"}


def lerobot(script: str, *flags: str, timeout: float = 600) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", f"lerobot.scripts.{script}", *flags]
    return run_command(command, env=ENV, timeout=timeout)


def rig_flags(calibration: Path, hand: str = "umi", *extra: str) -> list[str]:
    return ["--robot.type=opfa_sim", f"--robot.hand={hand}", "--robot.task=press_button",
            "--robot.depth_cameras=front", f"--robot.calibration_dir={calibration}", *extra]  # fmt: skip


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("rig")
    done = lerobot(
        "lerobot_record",
        *rig_flags(root / "calibration", "umi", "--robot.episode_time_s=1.5", "--robot.rgb_cameras=front"),
        "--teleop.type=opfa_expert",
        "--dataset.repo_id=local/rig", f"--dataset.root={root / 'rig'}", "--dataset.num_episodes=2",
        "--dataset.episode_time_s=1.5", "--dataset.reset_time_s=0", "--dataset.fps=20",
        "--dataset.single_task=press the button", "--dataset.push_to_hub=false", "--display_data=false",
        "--play_sounds=false",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return root


def test_lerobot_record_with_the_expert_writes_depth_episodes_and_logs_their_outcome(recorded):
    dataset = LeRobotDataset("local/rig", root=recorded / "rig")
    depth = dataset.meta.features["observation.images.front_depth"]
    assert depth["info"]["is_depth_map"] and tuple(depth["shape"]) == (96, 128, 1)
    assert dataset.meta.robot_type == "umi" and dataset.meta.total_episodes == 2
    assert dataset.meta.features["action"]["names"][-1] == "left_jaw_joint.pos"
    log = [json.loads(line) for line in (recorded / "calibration" / "opfa_sim_episodes.jsonl").open()]
    assert [o["episode"] for o in log] == [0, 1] and log[0]["ended"] == "time"
    frames = dataset.meta.episodes["length"]
    assert [o["steps"] for o in log] == list(frames), (log, frames)  # one scene per recorded episode
    frame = dataset[5]["observation.images.front_depth"]
    assert frame.shape == (1, 96, 128) and 200 < float(frame[frame > 0].median()) < 2000  # millimetres
    colour = dataset[5]["observation.images.front_rgb"]
    assert colour.shape == (3, 96, 128) and colour.dtype == torch.float32 and colour.std() > 0.05


@pytest.mark.parametrize("return_uint8", [False, True])
def test_the_in_memory_dataset_serves_the_recorded_video_frames_as_lerobot_does(recorded, return_uint8):
    """Also from a dataset opened as `lerobot-train` opens it (`return_uint8`: colour decoded as uint8),
    which `lerobot-opfa train` holds in memory: once, that read 0-255 frames as 0-1 and trained every RGB
    policy on wrapped colours."""
    from lerobot_opfa.datasets.in_memory import InMemoryDataset

    deltas = {"observation.images.front_rgb": [-0.05, 0.0], "observation.images.front_depth": [-0.05, 0.0],
              "action": [0.0, 0.05]}  # fmt: skip
    reference = LeRobotDataset("local/rig", root=recorded / "rig", delta_timestamps=deltas)
    held = InMemoryDataset(
        LeRobotDataset("local/rig", root=recorded / "rig", delta_timestamps=deltas, return_uint8=return_uint8)
    )
    for index in (0, 7, len(reference) - 1):
        expected, served = reference[index], held[index]
        for key in ("observation.images.front_rgb", "observation.images.front_depth", "action"):
            assert served[key].dtype == expected[key].dtype and served[key].shape == expected[key].shape
            assert torch.equal(served[key], expected[key]), (index, key)
            assert torch.equal(served[f"{key}_is_pad"], expected[f"{key}_is_pad"])


def test_an_rgb_policy_trains_on_the_rigs_colour_camera_and_acts_in_lerobot_eval(recorded, tmp_path):
    policy = {"type": "opfa", "action_space": "raw", "device": "cpu", "push_to_hub": "false", "horizon": 8,
              "down_dims": "[16,32]", "n_action_steps": 4, "visual_inputs": "rgb",
              "image_feature_dim": 8}  # fmt: skip
    train = ["train", *(f"--policy.{k}={v}" for k, v in policy.items()), "--dataset.repo_id=local/rig",
             f"--dataset.root={recorded / 'rig'}", "--steps=2", "--batch_size=2", "--save_freq=2",
             f"--output_dir={tmp_path / 'train'}", "--wandb.enable=false"]  # fmt: skip
    assert cli.main(train) == 0  # `lerobot-opfa train` in this process (LeRobot's loop; lerobot-eval below)
    checkpoint = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((checkpoint / "config.json").read_text())
    assert "observation.pointcloud" not in config["input_features"]
    assert config["input_features"]["observation.images.front_rgb"]["shape"] == [3, 96, 128]
    done = lerobot(
        "lerobot_eval", f"--policy.path={checkpoint}", "--env.type=opfa", "--env.task=press_button",
        "--env.hand=umi", "--env.obs_type=rgb", "--env.episode_length=12", "--eval.n_episodes=1",
        "--eval.batch_size=1", f"--output_dir={tmp_path / 'eval'}", "--policy.device=cpu",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1

    # The same loop read between steps: where the wrist ends against where the button was placed.
    config = OpfaEnvConfig(task="press_button", hand="umi", obs_type="rgb", episode_length=6)
    following = object_following(checkpoint, config, episodes=3, seed=0)
    assert following["following_episodes"] == 3 and np.isfinite(following["follows_object"])
    scatter = image_goal_scatter(checkpoint, config, episodes=3, seed=0)
    assert scatter["goal_episodes"] == 3 and np.isfinite(scatter["goal_scatter_cm"]).all()


def test_a_checkpoint_trained_on_the_rigs_depth_deploys_with_lerobot_rollout(recorded, tmp_path, monkeypatch):
    """Trained by `lerobot-train`'s entry point here, deployed by `lerobot-rollout` subprocesses."""
    calibration = recorded / "calibration" / "opfa_sim_cameras.yaml"
    policy = {"type": "opfa", "action_space": "raw", "device": "cpu", "push_to_hub": "false", "horizon": 8,
              "down_dims": "[16,32]", "n_action_steps": 4, "pointcloud_widths": "[8,16]",
              "pointcloud_feature_dim": 8, "cloud_points": 64, "cameras": calibration}  # fmt: skip
    run_lerobot_here("lerobot_train", [
        *(f"--policy.{k}={v}" for k, v in policy.items()), "--dataset.repo_id=local/rig",
        f"--dataset.root={recorded / 'rig'}", "--steps=2", "--batch_size=2", "--num_workers=0",
        "--save_freq=2", f"--output_dir={tmp_path / 'train'}", "--wandb.enable=false",
    ], monkeypatch)  # fmt: skip
    checkpoint = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    deploy = tmp_path / "deploy"
    common = [
        f"--policy.path={checkpoint}",
        "--fps=20",
        "--play_sounds=false",
        "--return_to_initial_position=false",
    ]
    flags = [*common, "--strategy.type=base", "--duration=2"]
    done = lerobot("lerobot_rollout", *rig_flags(deploy, "umi", "--robot.auto_reset=true"), *flags)
    assert done.returncode == 0, done.stderr[-3000:]
    log = [json.loads(line) for line in (deploy / "opfa_sim_episodes.jsonl").open()]
    assert log and all(o["hand"] == "umi" and o["task"] == "press_button" for o in log)
    assert sum(o["steps"] for o in log) >= 10, log  # the policy drove the rig
    episodic = tmp_path / "episodic"
    done = lerobot(
        "lerobot_rollout", *rig_flags(episodic, "umi", "--robot.episode_time_s=1"), *common,
        "--strategy.type=episodic", "--strategy.reset_to_initial_position=false",
        "--dataset.repo_id=local/rollout_rig",
        f"--dataset.root={tmp_path / 'rollout'}", "--dataset.num_episodes=2", "--dataset.episode_time_s=1",
        "--dataset.reset_time_s=0", "--dataset.single_task=press the button", "--dataset.push_to_hub=false",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    log = [json.loads(line) for line in (episodic / "opfa_sim_episodes.jsonl").open()]
    rollouts = LeRobotDataset("local/rollout_rig", root=tmp_path / "rollout")
    assert [o["steps"] for o in log] == list(rollouts.meta.episodes["length"]), log  # a scene per episode
    assert len(log) == 2 and "observation.images.front_depth" in rollouts.meta.features
    # A robot of another hand is refused by its robot_type, the 2F-85 too: it has umi's width (one joint).
    for other in ("inspire", "robotiq_2f85"):
        done = lerobot("lerobot_rollout", *rig_flags(tmp_path / other, other), *flags)
        last = done.stderr.strip().splitlines()[-1]
        assert done.returncode != 0 and last.startswith("error: this policy drives 'umi'"), done.stderr[
            -3000:
        ]
        assert f"robot_type '{other}'" in last and "Traceback" not in done.stderr, last
    accepted = tmp_path / "accepted"
    pin = ["policy", "for-robot", "--policy", str(checkpoint), "--hand", "umi", "--output", str(accepted)]
    assert cli.main([*pin, "--robot-type", "robotiq_2f85"]) == 0
    done = lerobot(
        "lerobot_rollout", *rig_flags(tmp_path / "accepted_run", "robotiq_2f85"), f"--policy.path={accepted}",
        *flags[1:],
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]


def test_an_episode_shorter_than_the_tasks_step_budget_is_reported_and_late_success_does_not_count(
    tmp_path, caplog, monkeypatch
):
    from lerobot_opfa.rig.robot import OpfaSimRobot, OpfaSimRobotConfig

    config = OpfaSimRobotConfig(hand="umi", task="press_button", calibration_dir=tmp_path, episode_time_s=0.2)
    robot = OpfaSimRobot(config)
    robot.connect()
    budget = robot.env.task.episode_steps
    hold = {k: v for k, v in robot.get_observation().items() if k in robot.action_features}
    for _ in range(3):
        robot.send_action(hold)
    time.sleep(0.3)
    with caplog.at_level("WARNING"):
        robot.get_observation()  # past episode_time_s: the scene resets
    assert f"ended after 3 of the task's {budget} steps" in caplog.text
    step = robot.env.step
    monkeypatch.setattr(robot.env, "step", lambda a: (*step(a)[:4], {"is_success": robot.steps >= budget}))
    for _ in range(budget + 1):
        robot.send_action(hold)
    robot.disconnect()
    log = [json.loads(line) for line in robot.episodes_log.open()]
    assert [o["success"] for o in log] == [False, False] and log[1]["steps"] == budget + 1


def test_the_two_armed_rig_records_with_lerobot_record_trains_without_a_map_and_deploys_with_lerobot_rollout(
    tmp_path, monkeypatch
):
    """`--robot.hand=inspire+xhand --robot.task=lift_tray`: LeRobot's recorder writes both arms' entries as
    its two-armed robots name them (`left_wrist_x.pos`, ..., `right_<joint>.pos`) and `robot_type`
    `inspire+xhand`, which is all training needs to read a latent per hand; `lerobot-rollout` drives it."""
    flags = ["--robot.type=opfa_sim", "--robot.hand=inspire+xhand", "--robot.task=lift_tray",
             "--robot.depth_cameras=front"]  # fmt: skip
    done = lerobot(
        "lerobot_record", *flags, f"--robot.calibration_dir={tmp_path / 'calibration'}",
        "--robot.episode_time_s=1", "--teleop.type=opfa_expert", "--dataset.repo_id=local/two",
        f"--dataset.root={tmp_path / 'two'}", "--dataset.num_episodes=2", "--dataset.episode_time_s=1",
        "--dataset.reset_time_s=0", "--dataset.fps=20", "--dataset.single_task=lift the tray",
        "--dataset.push_to_hub=false", "--display_data=false", "--play_sounds=false",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    dataset = LeRobotDataset("local/two", root=tmp_path / "two")
    names = dataset.meta.features["action"]["names"]
    assert dataset.meta.robot_type == "inspire+xhand" and names[0] == "left_wrist_x.pos"
    assert names[-1] == "right_little_pip_flex.pos"
    policy = {"type": "opfa", "device": "cpu", "push_to_hub": "false", "horizon": 8, "down_dims": "[16,32]",
              "n_action_steps": 4, "pointcloud_widths": "[8,16]", "pointcloud_feature_dim": 8,
              "cloud_points": 64, "cameras": tmp_path / "calibration" / "opfa_sim_cameras.yaml"}  # fmt: skip
    run_lerobot_here("lerobot_train", [
        *(f"--policy.{k}={v}" for k, v in policy.items()), "--dataset.repo_id=local/two",
        f"--dataset.root={tmp_path / 'two'}", "--steps=2", "--batch_size=2", "--num_workers=0",
        "--save_freq=2", f"--output_dir={tmp_path / 'train'}", "--wandb.enable=false",
    ], monkeypatch)  # fmt: skip
    checkpoint = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((checkpoint / "config.json").read_text())
    assert config["robots"] == [[0, 1]] and config["embodiments"] == ["inspire", "xhand"]
    deploy = tmp_path / "deploy"
    done = lerobot(
        "lerobot_rollout", *flags, f"--robot.calibration_dir={deploy}", "--robot.auto_reset=true",
        f"--policy.path={checkpoint}", "--fps=20", "--play_sounds=false",
        "--return_to_initial_position=false", "--strategy.type=base", "--duration=2",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    log = [json.loads(line) for line in (deploy / "opfa_sim_episodes.jsonl").open()]
    assert log and all(o["hand"] == "inspire+xhand" and o["task"] == "lift_tray" for o in log)
    assert sum(o["steps"] for o in log) >= 10, log  # the policy drove both arms
