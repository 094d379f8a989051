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
    assert joint_map.armed and layout.wrist_names[:3] == ["wrist.x", "wrist.y", "wrist.z"]
    state = torch.tensor(read_columns(ur5_demos, [OBS_STATE])[OBS_STATE], dtype=torch.float64)
    pose, _ = joint_map.split(state, OBS_STATE)
    approach = pose_matrix(pose)[:, :3, 2]  # the hand's fingers, along the wrist frame's +z
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
