"""The two-armed scene: each arm a wrist carriage with its hand, a task that needs both hands (`lift_tray`,
a tray in two halves on a hinge) and its scripted expert, run in MuJoCo."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_opfa.datasets.joint_map import SIDES
from lerobot_opfa.envs.env import OpfaSimEnv
from lerobot_opfa.envs.experts import ScriptedExpert
from lerobot_opfa.envs.scene import WRIST_JOINTS
from lerobot_opfa.envs.tasks import parse_hands
from lerobot_opfa.hands import load_hand


def run_expert(env: OpfaSimEnv, seed: int, one_arm: bool = False) -> bool:
    """One seeded episode of the expert (with `one_arm`, the right arm stays home, its hand open)."""
    env.reset(seed=seed)
    expert = ScriptedExpert(env, np.random.default_rng(seed))
    right = env.arm("right")
    home = np.concatenate([right.home, right.hand_open])
    for _ in range(env.task.episode_steps):
        action = expert.act()
        if one_arm:
            action[-len(home) :] = home
        if env.step(action)[2]:
            return True
    return False


@pytest.fixture(scope="module")
def env():
    env = OpfaSimEnv("lift_tray", "inspire+xhand", obs_type="state")
    yield env
    env.close()


def test_each_arm_holds_its_hand_and_the_entries_name_the_side(env):
    inspire, xhand = load_hand("inspire"), load_hand("xhand")
    assert env.state_names == [
        *(f"left_{n}" for n in (*WRIST_JOINTS, *inspire.joint_names)),
        *(f"right_{n}" for n in (*WRIST_JOINTS, *xhand.joint_names)),
    ]
    obs, _ = env.reset(seed=0)
    assert obs["agent_pos"].shape == env.action_space.shape == (12 + inspire.dof + xhand.dof,)
    left, right = obs["agent_pos"][:3], obs["agent_pos"][6 + inspire.dof : 9 + inspire.dof]
    assert left[1] > 0.1 and right[1] < -0.1, "the left wrist stands at +y, the right at -y"
    assert parse_hands("inspire, xhand") == parse_hands(["inspire", "xhand"]) == ["inspire", "xhand"]
    with pytest.raises(ValueError, match="two hands, left then right"):
        parse_hands("inspire")


def test_the_two_armed_expert_lifts_the_tray_level_and_one_arm_alone_never_does(env):
    assert sum(run_expert(env, seed) for seed in range(8)) >= 7
    assert not any(run_expert(env, seed, one_arm=True) for seed in range(4)), "one hand folds the tray"
    assert set(env.task.handles(env.placement)) == set(SIDES)


def test_two_arms_get_the_one_arm_scenes_colour_camera_and_ee_delta_control_arm_by_arm():
    """The two-armed scene is the same env class: colour pictures, and `ee_delta` control of a gripper on
    each arm (each arm's step and grasp, its state named by side), the expert's targets reached through it."""
    env = OpfaSimEnv("lift_tray", "umi+robotiq_2f85", obs_type="rgb", control="ee_delta", camera_width=64,
                     camera_height=48)  # fmt: skip
    obs, _ = env.reset(seed=0)
    assert obs["pixels"]["front_rgb"].shape == (48, 64, 3) and obs["pixels"]["front_rgb"].std() > 0
    assert env.action_names == [f"{side}_{n}" for side in SIDES for n in ("dx", "dy", "dz", "dyaw", "grasp")]
    assert env.state_names[0] == "left_wrist_x" and env.state_names[-1] == "right_gripper"
    assert env.joint_map is None, "ee_delta entries are read through the map a policy was trained with"
    assert obs["agent_pos"].shape == (26,) and env.action_space.shape == (10,)
    expert = ScriptedExpert(env, np.random.default_rng(0))
    for _ in range(30):
        obs = env.step(env.command(expert.act()))[0]
    targets = expert.act()
    left, right = obs["agent_pos"][:3], obs["agent_pos"][13:16]
    assert np.abs(left - targets[:3]).max() < 0.03 and np.abs(right - targets[7:10]).max() < 0.03
    assert left[1] > 0 > right[1], "each arm's steps move its own wrist"
    env.close()


def test_two_hand_demos_train_one_policy_that_lerobot_eval_runs_in_the_two_armed_env(tmp_path, monkeypatch):
    """`sim demos` of `lift_tray` with Inspire on the left and XHand on the right records the joint map of
    its entries; `lerobot-opfa train` reads it (a latent per hand) and `lerobot-eval --env.type=opfa` runs
    the checkpoint in the two-armed env, its actions through the same map."""
    import json

    from subprocesses import run_lerobot_here

    from lerobot_opfa import cli
    from lerobot_opfa.policy.modeling_opfa import OpfaPolicy

    demos, out = tmp_path / "demos", tmp_path / "train"
    scene = ["--n-points", "64", "--pointcloud-source", "geometry"]
    record = ["sim", "demos", "--task", "lift_tray", "--hand", "inspire+xhand", "--episodes", "2",
              "--regions", "mid_center", "--output-dir", str(demos), *scene]  # fmt: skip
    assert cli.main(record) == 0
    train = ["train", "--policy.type=opfa", "--dataset.repo_id=local/demos", f"--dataset.root={demos}",
             "--policy.device=cpu", "--policy.push_to_hub=false", "--policy.down_dims=[16,32]",
             "--policy.horizon=8", "--policy.n_action_steps=4", "--policy.pointcloud_widths=[16,32]",
             "--policy.pointcloud_feature_dim=16", "--policy.n_groups=4", "--steps=2", "--batch_size=4",
             "--save_freq=2", "--num_workers=0", f"--output_dir={out}", "--wandb.enable=false"]  # fmt: skip
    assert cli.main(train) == 0
    checkpoint = out / "checkpoints" / "last" / "pretrained_model"
    config = OpfaPolicy.from_pretrained(checkpoint).config
    assert config.embodiments == ["inspire", "xhand"] and config.robots == [[0, 1]]
    assert config.action_width == 12 + 2 * config.latent_dim
    evaluate = [f"--policy.path={checkpoint}", "--env.type=opfa", "--env.task=lift_tray",
                "--env.hand=inspire+xhand", "--env.n_points=64", "--env.pointcloud_source=geometry",
                "--env.regions=mid_center", "--eval.n_episodes=1", "--eval.batch_size=1",
                f"--output_dir={tmp_path / 'eval'}", "--env.episode_length=20"]  # fmt: skip
    run_lerobot_here("lerobot_eval", evaluate, monkeypatch)
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1


def test_a_policy_of_two_pairs_of_hands_drives_the_mixed_pair_in_the_simulator_and_no_robot_of_it(tmp_path):
    """Co-trained on (Inspire, Inspire) and (XHand, XHand), a policy takes the simulator's frames of
    (Inspire, XHand), each slot decoded into its own hand; a robot of that pair has no trained joint map."""
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.utils.constants import OBS_STATE
    from test_policy import make_policy, save_galr

    from lerobot_opfa import cli
    from lerobot_opfa.features import OBS_POINTCLOUD, ROBOT_TYPE
    from lerobot_opfa.policy.joint_steps import OpfaEncodeJointsStep

    save_galr(tmp_path / "galr", ["inspire", "xhand"])
    for pair in ("inspire+inspire", "xhand+xhand"):
        record = ["sim", "demos", "--task", "lift_tray", "--hand", pair, "--episodes", "1", "--regions",
                  "mid_center", "--output-dir", str(tmp_path / pair), "--n-points", "32",
                  "--pointcloud-source", "geometry"]  # fmt: skip
        assert cli.main(record) == 0
    merge = ["dataset", "merge", "--inputs", str(tmp_path / "inspire+inspire"), str(tmp_path / "xhand+xhand"),
             "--output", str(tmp_path / "merged"), "--galr", str(tmp_path / "galr")]  # fmt: skip
    assert cli.main(merge) == 0
    assert (
        LeRobotDatasetMetadata("local/merged", root=tmp_path / "merged").features[OBS_STATE]["shape"][0] > 12
    )
    policy, pre, post, _ = make_policy(tmp_path, "merged")
    env = OpfaSimEnv(
        "lift_tray", "inspire+xhand", obs_type="pointcloud", pointcloud_source="geometry", n_points=32
    )
    obs, _ = env.reset(seed=0)
    observation = {OBS_STATE: torch.tensor(obs["agent_pos"]).float(), ROBOT_TYPE: env.hand_name,
                   OBS_POINTCLOUD: torch.tensor(obs["pointcloud"]).float()}  # fmt: skip
    with torch.no_grad():
        action = post(policy.select_action(pre(observation)))
    assert action.shape == (1, len(env.action_names)), "the mixed pair's entries: 12 wrist, 6 + 12 joints"
    assert np.all(np.isfinite(action.numpy()))
    env.close()
    encoder = next(step for step in pre.steps if isinstance(step, OpfaEncodeJointsStep))
    with pytest.raises(ValueError, match="it cannot drive inspire\\+xhand"):
        encoder.trained_map((0, 1))
