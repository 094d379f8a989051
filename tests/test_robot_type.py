"""A deployed robot's `robot_type` reaches the preprocessor (`policy/robot_type.py`) and picks or refuses
the robot a checkpoint drives. The rig's refusal through `lerobot-rollout` is in test_rig.py."""

from __future__ import annotations

import pytest
import torch
from lerobot.processor import TransitionKey
from lerobot.processor.converters import batch_to_transition

import lerobot_policy_opfa  # noqa: F401  (the plugin registers robot_type, as LeRobot's CLIs load it)
from lerobot_opfa.policy.joint_steps import OpfaEncodeJointsStep


def encode_step(*hands: str, **fields) -> OpfaEncodeJointsStep:
    """A raw-space encode step of one one-handed robot per hand (umi and the 2F-85: one joint each)."""
    return OpfaEncodeJointsStep(action_space="raw", embodiments=list(hands), hand_refs=list(hands), **fields)


def robot_of(step: OpfaEncodeJointsStep, robot_type: str) -> list[list[int]]:
    """The embodiment ids the step gives a frame of a `robot_type` robot, batched as lerobot-rollout does."""
    batch = {"observation.state": torch.zeros(1, 7), "robot_type": robot_type}
    return step(batch_to_transition(batch))[TransitionKey.OBSERVATION]["observation.embodiment"].tolist()


def test_lerobots_batch_converter_keeps_the_robot_type():
    """Fails when LeRobot's converters stop reading `_COMPLEMENTARY_KEYS` at call time."""
    transition = batch_to_transition({"observation.state": torch.zeros(1, 7), "robot_type": "umi"})
    assert transition[TransitionKey.COMPLEMENTARY_DATA]["robot_type"] == "umi"


def test_a_checkpoint_of_several_robots_picks_its_robot_from_the_robot_type():
    step = encode_step("umi", "robotiq_2f85")
    assert robot_of(step, "robotiq_2f85") == [[1]] and robot_of(step, "umi") == [[0]]
    assert robot_of(step, "ur5_robotiq_2f85") == [[1]]  # a word of it names the hand
    with pytest.raises(ValueError, match="drives several robots"):
        robot_of(step, "so101_follower")


def test_a_robot_of_another_hand_is_refused_in_one_line_and_runs_by_the_users_word():
    step = encode_step("umi")
    assert robot_of(step, "umi") == [[0]] and robot_of(step, "so101_follower") == [[0]]  # names no hand
    with pytest.raises(ValueError) as refused:
        robot_of(step, "robotiq_2f85")
    message = str(refused.value)
    assert "drives 'umi'" in message and "robot_type 'robotiq_2f85'" in message and "\n" not in message
    assert "--robot-type robotiq_2f85" in message
    assert robot_of(encode_step("umi", accept_robot_type="robotiq_2f85"), "robotiq_2f85") == [[0]]
    assert robot_of(encode_step("umi", hand="umi"), "so101_follower") == [[0]]
    with pytest.raises(ValueError, match="names hand\\(s\\) robotiq_2f85"):
        robot_of(encode_step("umi", hand="umi"), "robotiq_2f85")


def test_a_robot_on_an_arm_is_refused_by_a_policy_of_the_floating_wrist_and_runs_on_a_body_kept_as_recorded():
    """Both have six body entries and the umi's jaw: a UR5's joints would be read as the simulator's wrist
    pose without a word. A policy whose body entries are a recorded robot's own (not modelled) says
    nothing."""
    from lerobot_opfa.datasets.joint_map import JointMap
    from lerobot_opfa.envs.scene import WRIST_JOINTS
    from lerobot_opfa.hands.registry import load_spec

    names = [*WRIST_JOINTS, "left_jaw_joint"]
    floating = JointMap.named_after(load_spec("umi"), names, names).to_dict()
    with pytest.raises(ValueError, match="drives 'umi' on the floating wrist, but .* names arm\\(s\\) ur5"):
        robot_of(encode_step("umi", joint_maps=[floating]), "ur5_umi")
    assert robot_of(encode_step("umi"), "ur5_umi") == [[0]]
    assert robot_of(encode_step("umi", joint_maps=[floating], accept_robot_type="ur5_umi"), "ur5_umi") == [
        [0]
    ]
