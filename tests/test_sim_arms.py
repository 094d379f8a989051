"""Hands on arms in the simulator: `sim demos --arm` records the arm's joints (as its model names them) at the
robot's own rate, the scripted expert reaching through IK; the dataset says its joint map, trains with no
user map, and `lerobot-eval --env.arm` runs the checkpoint on that arm and refuses it on another."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.utils.constants import OBS_STATE
from subprocesses import run_lerobot_here

from lerobot_opfa import cli
from lerobot_opfa.arms.pose import pose_matrix
from lerobot_opfa.arms.spec import load_arm
from lerobot_opfa.datasets.io import read_columns
from lerobot_opfa.datasets.layout import read_layout
from lerobot_opfa.envs.env import OpfaSimEnv
from lerobot_opfa.envs.experts import ScriptedExpert

os.environ.setdefault("MUJOCO_GL", "egl")

SCENE = ["--n-points", "64", "--pointcloud-source", "geometry"]


@pytest.fixture(scope="module")
def ur5_demos(tmp_path_factory):
    root = tmp_path_factory.mktemp("arms") / "ur5_umi"
    record = ["sim", "demos", "--task", "lift", "--hand", "umi", "--arm", "ur5", "--fps", "30", "--episodes",
              "2", "--regions", "mid_center", "--output-dir", str(root), *SCENE]  # fmt: skip
    assert cli.main(record) == 0
    return root


def test_arm_demos_record_the_arms_joints_at_the_robots_rate_and_read_as_the_wrist_pose(ur5_demos):
    meta = LeRobotDatasetMetadata("local/ur5_umi", root=ur5_demos)
    joints = list(load_arm("ur5").joints)
    assert meta.robot_type == "ur5_umi" and meta.fps == 30 and meta.total_episodes == 2
    assert meta.features[OBS_STATE]["names"] == [*joints, "left_jaw_joint"]
    layout = read_layout(meta.features, meta.robot_type, ur5_demos)  # the dataset says its map
    joint_map = layout.joint_maps[0]
    assert joint_map.armed and layout.wrist_names[:3] == ["tool.x", "tool.y", "tool.z"]
    state = torch.tensor(read_columns(ur5_demos, [OBS_STATE])[OBS_STATE], dtype=torch.float64)
    pose, _ = joint_map.split(state, OBS_STATE)
    approach = pose_matrix(pose)[:, :3, 2]  # the tool frame's approach axis
    assert (pose[:, 2] > 0).all() and (approach[:, 2] < -0.9).all(), "the hand above the table, pointing down"


def test_on_an_arm_the_expert_reaches_its_targets_through_ik():
    """The wrist the arm's joints put the hand at follows the expert's targets as the floating wrist does."""
    env = OpfaSimEnv("lift", "inspire", obs_type="state", arm="panda")
    obs, _ = env.reset(seed=3, options={"region": "near_left"})
    expert = ScriptedExpert(env, np.random.default_rng(3))
    arm = env.scene.arms[None]
    for _ in range(30):
        targets = expert.act()
        obs, *_ = env.step(env.command(targets))
    assert np.abs(env.data.qpos[arm.wrist_qpos][:3] - targets[:3]).max() < 0.03
    assert obs["agent_pos"].shape == (7 + 6,)
    env.close()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"task": "lift_tray", "hand": "inspire+xhand"}, "an arm carries one hand"),
     ({"control": "ee_delta"}, "acts in its joints")],
)  # fmt: skip
def test_an_arm_on_two_hands_or_under_ee_delta_is_one_line(kwargs, message):
    with pytest.raises(ValueError, match=message):
        OpfaSimEnv(**{"task": "lift", "hand": "umi", "obs_type": "state", "arm": "ur5", **kwargs})


def test_a_policy_trained_on_arm_demos_runs_on_that_arm_in_lerobot_eval_and_is_refused_on_another(
    ur5_demos, tmp_path, monkeypatch, capsys
):
    out = tmp_path / "train"
    train = ["train", "--policy.type=opfa", "--dataset.repo_id=local/ur5_umi", f"--dataset.root={ur5_demos}",
             "--policy.device=cpu", "--policy.push_to_hub=false", "--policy.down_dims=[16,32]",
             "--policy.horizon=8", "--policy.n_action_steps=4", "--policy.pointcloud_widths=[16,32]",
             "--policy.pointcloud_feature_dim=16", "--policy.n_groups=4", "--steps=2", "--batch_size=4",
             "--save_freq=2", "--num_workers=0", f"--output_dir={out}", "--wandb.enable=false"]  # fmt: skip
    assert cli.main(train) == 0
    checkpoint = out / "checkpoints" / "last" / "pretrained_model"
    evaluate = [f"--policy.path={checkpoint}", "--env.type=opfa", "--env.task=lift", "--env.hand=umi",
                "--env.n_points=64", "--env.pointcloud_source=geometry", "--env.regions=mid_center",
                "--eval.n_episodes=1", "--eval.batch_size=1", "--env.episode_length=6"]  # fmt: skip
    ur5 = [*evaluate, "--env.arm=ur5", "--env.fps=30", f"--output_dir={tmp_path / 'eval'}"]
    run_lerobot_here("lerobot_eval", ur5, monkeypatch)
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1
    with pytest.raises(SystemExit):
        run_lerobot_here("lerobot_eval", [*evaluate, "--env.arm=panda"], monkeypatch)
    refused = capsys.readouterr().err.strip().splitlines()[-1]
    assert refused.startswith("error: `env.arm`: the policy at") and "none of them this arm's" in refused


def test_the_rig_on_an_arm_records_with_lerobot_record_and_deploys_with_lerobot_rollout_on_that_arm_only(
    tmp_path, monkeypatch
):
    """`--robot.arm=ur5` on the `opfa_sim` rig: `lerobot-record` with the expert writes the arm's joints as
    LeRobot's robots name them (`<joint>.pos`); a map naming the arm trains on them (the wrist pose) and
    `lerobot-rollout` drives the rig's arm; a rig on another arm is refused in one line naming both."""
    from test_rig import lerobot, rig_flags

    arm = ["--robot.arm=ur5", "--robot.task=lift"]
    done = lerobot(
        "lerobot_record", *rig_flags(tmp_path / "calibration", "umi", *arm, "--robot.episode_time_s=1"),
        "--teleop.type=opfa_expert", "--dataset.repo_id=local/rig_ur5", f"--dataset.root={tmp_path / 'rig'}",
        "--dataset.num_episodes=2", "--dataset.episode_time_s=1", "--dataset.reset_time_s=0",
        "--dataset.fps=20", "--dataset.single_task=lift", "--dataset.push_to_hub=false",
        "--display_data=false", "--play_sounds=false",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    meta = LeRobotDatasetMetadata("local/rig_ur5", root=tmp_path / "rig")
    assert meta.robot_type == "ur5_umi"
    assert meta.features[OBS_STATE]["names"] == [
        *(f"{j}.pos" for j in load_arm("ur5").joints),
        "left_jaw_joint.pos",
    ]
    joint_map = tmp_path / "ur5_umi.yaml"
    joint_map.write_text("hand: umi\njoints: {left_jaw_joint.pos: left_jaw_joint}\narm: ur5\n")
    calibration = tmp_path / "calibration" / "opfa_sim_cameras.yaml"
    policy = {"type": "opfa", "action_space": "raw", "device": "cpu", "push_to_hub": "false", "horizon": 8,
              "down_dims": "[16,32]", "n_action_steps": 4, "pointcloud_widths": "[8,16]",
              "pointcloud_feature_dim": 8, "cloud_points": 64, "cameras": calibration,
              "joint_map": joint_map}  # fmt: skip
    run_lerobot_here("lerobot_train", [
        *(f"--policy.{k}={v}" for k, v in policy.items()), "--dataset.repo_id=local/rig_ur5",
        f"--dataset.root={tmp_path / 'rig'}", "--steps=2", "--batch_size=2", "--num_workers=0",
        "--save_freq=2", f"--output_dir={tmp_path / 'train'}", "--wandb.enable=false",
    ], monkeypatch)  # fmt: skip
    checkpoint = tmp_path / "train" / "checkpoints" / "last" / "pretrained_model"
    flags = [f"--policy.path={checkpoint}", "--fps=20", "--play_sounds=false",
             "--return_to_initial_position=false", "--strategy.type=base", "--duration=2"]  # fmt: skip
    deploy = tmp_path / "deploy"
    done = lerobot("lerobot_rollout", *rig_flags(deploy, "umi", *arm, "--robot.auto_reset=true"), *flags)
    assert done.returncode == 0, done.stderr[-3000:]
    log = [json.loads(line) for line in (deploy / "opfa_sim_episodes.jsonl").open()]
    assert sum(o["steps"] for o in log) >= 10, log  # the policy drove the rig's arm
    panda = ["--robot.arm=panda", "--robot.task=lift"]
    done = lerobot("lerobot_rollout", *rig_flags(tmp_path / "panda", "umi", *panda), *flags)
    last = done.stderr.strip().splitlines()[-1]
    assert done.returncode != 0 and "robot_type 'panda_umi' names arm(s) panda" in last, done.stderr[-3000:]
    assert "on ur5" in last and "Traceback" not in done.stderr
