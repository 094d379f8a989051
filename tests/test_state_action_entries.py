"""A robot whose state and action hold different entries, as a gripper on an arm with a Cartesian
controller records them: the action is tool steps (`dx, dy, dz, dyaw`) and a 0..1 `grasp` command, the
state the wrist's joints and velocities and a -1..1 `gripper` reading (the simulator's `ee_delta`
control). A joint map with `state_joints` / `action_joints` reads it as recorded: it maps, trains with
`lerobot-train` and evaluates with `lerobot-eval`, with no renaming."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest
import torch
from lerobot.utils.constants import ACTION, OBS_STATE
from subprocesses import run_command, run_lerobot_here

from lerobot_opfa.cli import main
from lerobot_opfa.datasets.joint_map import JointMap, JointMapError
from lerobot_opfa.envs.config import OpfaEnvConfig
from lerobot_opfa.envs.control import EE_ACTION_NAMES, EE_STATE_NAMES, EndEffectorDeltas
from lerobot_opfa.envs.scene import HOME
from lerobot_opfa.flags import FlagError
from lerobot_opfa.hands.registry import load_hand

ENV = {**os.environ, "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
N_POINTS = 64
JAW = "left_jaw_joint"  # umi's one actuated joint (metres)


def ee_map(path: Path) -> Path:
    """umi's jaw from the -1 (open) .. 1 (closed) reading and from the 0 (open) .. 1 (closed) command."""
    control = EndEffectorDeltas(load_hand("umi"), HOME)
    travel, middle = control.closed - control.open, (control.closed + control.open) / 2
    path.write_text(
        "hand: umi\n"
        f"state_joints:\n  gripper: {{joint: {JAW}, scale: {travel / 2!r}, offset: {middle!r}}}\n"
        f"action_joints:\n  grasp: {{joint: {JAW}, scale: {travel!r}, offset: {control.open!r}}}\n"
    )
    return path


@pytest.fixture(scope="module")
def ee_demos(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ee") / "press_umi_ee"
    code = main([
        "sim", "demos", "--task", "press_button", "--hand", "umi", "--episodes", "2",
        "--regions", "mid_center", "--output-dir", str(root), "--n-points", str(N_POINTS),
        "--pointcloud-source", "geometry", "--control", "ee_delta",
    ])  # fmt: skip
    assert code == 0
    return root


def test_state_and_action_joints_apart_split_and_join_each_in_its_units(tmp_path):
    joint_map = JointMap.load(ee_map(tmp_path / "map.yaml")).bind(list(EE_STATE_NAMES), list(EE_ACTION_NAMES))
    assert joint_map.body_names(OBS_STATE) == list(EE_STATE_NAMES[:-1])  # wrist joints and velocities
    assert joint_map.body_names(ACTION) == ["dx", "dy", "dz", "dyaw"]
    control = EndEffectorDeltas(load_hand("umi"), HOME)
    state = torch.tensor([[0.0] * 12 + [-1.0], [0.0] * 12 + [1.0]], dtype=torch.float64)
    _, (jaw,) = joint_map.split(state, OBS_STATE)
    assert torch.allclose(jaw[:, 0], torch.tensor([control.open, control.closed], dtype=torch.float64))
    action = torch.tensor([[0.01, 0.0, -0.02, 0.1, 0.25]], dtype=torch.float64)
    body, (jaw,) = joint_map.split(action, ACTION)
    assert torch.allclose(
        jaw[0, 0], torch.tensor(control.open + 0.25 * (control.closed - control.open)).double()
    )
    assert torch.allclose(joint_map.join(body, [jaw]), action)


def test_a_map_that_misses_a_keys_joint_names_the_key_and_the_sections(tmp_path):
    shared = tmp_path / "shared.yaml"
    shared.write_text(f"hand: umi\njoints:\n  gripper: {JAW}\n")
    with pytest.raises(
        JointMapError, match="entry 'gripper' is not in the dataset's action .*'action_joints'"
    ):
        JointMap.load(shared).bind(list(EE_STATE_NAMES), list(EE_ACTION_NAMES))
    state_only = tmp_path / "state_only.yaml"
    state_only.write_text(f"hand: umi\nstate_joints:\n  gripper: {JAW}\n")
    with pytest.raises(JointMapError, match=r"once in action .*missing \['left_jaw_joint'\]"):
        JointMap.load(state_only).bind(list(EE_STATE_NAMES), list(EE_ACTION_NAMES))


def test_the_expert_succeeds_under_ee_delta_and_its_demos_name_their_own_entries(ee_demos):
    info = json.loads((ee_demos / "meta" / "info.json").read_text())
    assert info["features"][OBS_STATE]["names"] == list(EE_STATE_NAMES)
    assert info["features"][ACTION]["names"] == list(EE_ACTION_NAMES)
    demos = json.loads((ee_demos / "meta" / "opfa_demos.json").read_text())
    assert demos["attempts"] == 2  # both expert episodes succeeded: the deltas replay its targets


def test_a_merge_refuses_a_robot_whose_action_body_is_not_its_states(ee_demos, tmp_path, capsys):
    code = main([
        "dataset", "merge", "--inputs", str(ee_demos), "--output", str(tmp_path / "merged"),
        "--joint-maps", str(ee_map(tmp_path / "map.yaml")),
    ])  # fmt: skip
    error = capsys.readouterr().err
    assert code != 0 and "its action's body entries ['dx', 'dy', 'dz', 'dyaw'] are not its state's" in error
    assert not (tmp_path / "merged").exists()


def test_a_stock_policys_latent_dataset_of_the_ee_delta_robot_keeps_each_keys_body(ee_demos, tmp_path):
    code = main([
        "policy", "latent-dataset", "--input", str(ee_demos), "--output", str(tmp_path / "latent"),
        "--joint-map", str(ee_map(tmp_path / "map.yaml")),
    ])  # fmt: skip
    assert code == 0
    features = json.loads((tmp_path / "latent" / "meta" / "info.json").read_text())["features"]
    state, action = features[OBS_STATE]["names"], features[ACTION]["names"]
    assert state[:12] == list(EE_STATE_NAMES[:12]) and action[:4] == ["dx", "dy", "dz", "dyaw"]
    assert state[12:] == action[4:] and state[12] == "z0"  # the jaw's latent, read from each key's entry


def test_a_command_read_the_wrong_way_round_is_refused_naming_the_joint(ee_demos, tmp_path, capsys):
    """The grasp command's scale with its sign flipped (and the offset that keeps it within the jaw's
    limits): every value is a jaw opening the hand can reach, the jaw commanded shut where the demos opened
    it."""
    control = EndEffectorDeltas(load_hand("umi"), HOME)
    travel, middle = control.closed - control.open, (control.closed + control.open) / 2
    reversed_map = tmp_path / "reversed.yaml"
    reversed_map.write_text(
        "hand: umi\n"
        f"state_joints:\n  gripper: {{joint: {JAW}, scale: {travel / 2!r}, offset: {middle!r}}}\n"
        f"action_joints:\n  grasp: {{joint: {JAW}, scale: {-travel!r}, offset: {control.closed!r}}}\n"
    )
    code = main([
        "policy", "latent-dataset", "--input", str(ee_demos), "--output", str(tmp_path / "latent"),
        "--joint-map", str(reversed_map),
    ])  # fmt: skip
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and f"joint '{JAW}' runs against itself" in error, error
    assert "('gripper') follows its command ('grasp') with correlation -" in error
    assert not (tmp_path / "latent").exists()


def test_lerobot_train_then_lerobot_eval_on_the_ee_delta_robot_with_no_renaming(
    ee_demos, tmp_path, monkeypatch
):
    """`lerobot-train` as a subprocess, then `lerobot-eval`'s entry point in this process."""
    bin_dir = Path(sys.executable).parent
    out = tmp_path / "train"
    train = run_command([
        bin_dir / "lerobot-train", "--policy.type=opfa",
        f"--policy.joint_map={ee_map(tmp_path / 'map.yaml')}",
        "--dataset.repo_id=local/press_umi_ee", f"--dataset.root={ee_demos}", "--policy.device=cpu",
        "--policy.push_to_hub=false", "--policy.down_dims=[16,32]", "--policy.horizon=8",
        "--policy.n_action_steps=4", "--policy.pointcloud_widths=[16,32]",
        "--policy.pointcloud_feature_dim=16",
        "--policy.n_groups=4", "--steps=2", "--batch_size=4", "--save_freq=2", "--log_freq=1",
        "--num_workers=0", f"--output_dir={out}", "--wandb.enable=false",
    ], env=ENV, timeout=600)  # fmt: skip
    assert train.returncode == 0, train.stdout[-3000:] + train.stderr[-3000:]
    checkpoint = out / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((checkpoint / "config.json").read_text())
    assert config["wrist_names"] == list(EE_STATE_NAMES[:-1])
    assert config["action_body_names"] == ["dx", "dy", "dz", "dyaw"]

    evaluated = tmp_path / "eval"
    run_lerobot_here("lerobot_eval", [
        f"--policy.path={checkpoint}", "--env.type=opfa", "--env.task=press_button",
        "--env.hand=umi", "--env.control=ee_delta", "--env.regions=mid_center",
        "--env.pointcloud_source=geometry",
        f"--env.n_points={N_POINTS}", "--env.episode_length=6", "--eval.n_episodes=1", "--eval.batch_size=1",
        "--policy.device=cpu", f"--output_dir={evaluated}",
    ], monkeypatch)  # fmt: skip
    assert json.loads((evaluated / "eval_info.json").read_text())["overall"]["n_episodes"] == 1
    monkeypatch.setattr(
        sys, "argv", ["lerobot-eval", f"--policy.path={checkpoint}"]
    )  # as lerobot-eval reads it
    with pytest.raises(
        FlagError, match=r"`env.control`: joints, but the policy at .* --env.control=ee_delta"
    ):
        OpfaEnvConfig(task="press_button", hand="umi")  # the control left at its default


def test_ee_delta_control_of_a_dexterous_hand_is_one_line_naming_the_flag():
    with pytest.raises(FlagError, match=r"`env.control`: control ee_delta drives a gripper .* 'leap' has 16"):
        OpfaEnvConfig(hand="leap", control="ee_delta")
    with pytest.raises(FlagError, match="unknown control 'delta'; valid controls: joints, ee_delta"):
        OpfaEnvConfig(hand="umi", control="delta")
