"""Robots of different arms co-train: a joint map that names the arm reads its joints as the wrist's pose in
the workspace (FK), the policy models that pose whatever the arm, and the postprocessor turns it back into
each robot's own arm joints by IK seeded at the joints the arm holds."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
import yaml
from lerobot.processor import TransitionKey, create_transition
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa import cli
from lerobot_opfa.arms.ik import pose_error
from lerobot_opfa.arms.pose import POSE_NAMES, pose_matrix, rotation_vector_matrix
from lerobot_opfa.arms.spec import load_arm
from lerobot_opfa.datasets.io import read_columns
from lerobot_opfa.datasets.joint_map import DEGREE, JointMap, JointMapError
from lerobot_opfa.datasets.layout import read_layout
from lerobot_opfa.datasets.synthetic import write_armed_dataset
from lerobot_opfa.features import OBS_POINTCLOUD, ROBOT_TYPE
from lerobot_opfa.hands.registry import load_spec

ROBOTS = {"ur5_inspire": ("ur5", "inspire", 30), "panda_umi": ("panda", "umi", 10)}
"""Robot -> (arm, hand, fps): two robots that differ in arm, hand and rate."""


def write_map(path: Path, arm: str, hand: str, **extra) -> Path:
    joints = {joint: joint for joint in load_spec(hand).actuated_joints}
    path.write_text(yaml.safe_dump({"hand": hand, "joints": joints, "arm": arm, **extra}))
    return path


def recorded(root: Path) -> dict[str, torch.Tensor]:
    columns = read_columns(root, [OBS_STATE, ACTION])
    return {key: torch.tensor(values, dtype=torch.float64) for key, values in columns.items()}


def armed_layout(tmp_path: Path, robot: str):
    arm, hand, fps = ROBOTS[robot]
    root = write_armed_dataset(tmp_path / robot, arm, hand, frames=20, n_points=32, fps=fps)
    from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata

    meta = LeRobotDatasetMetadata(f"local/{robot}", root=root)
    joint_map = JointMap.load(write_map(tmp_path / f"{robot}.yaml", arm, hand))
    return read_layout(meta.features, meta.robot_type, root, joint_map=joint_map), root


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_an_arms_joints_round_trip_through_the_wrist_pose_within_a_millimetre(tmp_path, robot):
    """Recorded arm joints -> the wrist pose (the body the policy models, named alike for every arm) -> IK
    seeded at the state's joints -> the recorded action's joints: within 1 mm / 0.5 deg of its pose, the
    hand's entries exact."""
    layout, root = armed_layout(tmp_path, robot)
    joint_map, frames = layout.joint_maps[0], recorded(root)
    assert layout.wrist_names == [f"tool.{name}" for name in POSE_NAMES]
    body, qs = joint_map.split(frames[ACTION], ACTION)
    arm = joint_map.arm(joint_map.slots[0])
    (recorded_arm,) = joint_map.arm_joints(frames[ACTION], ACTION)
    assert torch.allclose(body, arm.pose(recorded_arm), atol=1e-9)
    arms, missed, _ = joint_map.reach(body, frames[OBS_STATE])
    action = joint_map.join(body, qs, arms)
    assert missed == 0 and action.shape == frames[ACTION].shape
    error = pose_error(pose_matrix(arm.pose(arms[0])), pose_matrix(body))
    assert error[:, :3].norm(dim=-1).max() < 1e-3 and error[:, 3:].norm(dim=-1).max() < math.radians(0.5)
    hand_columns = slice(len(arm.spec.joints), None)
    assert torch.equal(action[:, hand_columns], frames[ACTION][:, hand_columns])
    _, _, held_back = joint_map.reach(body, frames[OBS_STATE], seconds=1 / ROBOTS[robot][2])
    assert held_back == 0, "a recorded action is one the arm makes at its rate"


def test_an_action_far_from_the_held_joints_moves_the_arm_no_faster_than_its_velocity_limits(tmp_path):
    """A chunk of poses on the far side of the workspace (IK converges there, or does not): each action
    moves every joint at most its velocity limit times the time between actions, the first from the joints
    held, and the step counts them; without a rate, IK jumps there at once."""
    layout, root = armed_layout(tmp_path, "ur5_inspire")
    joint_map, frames = layout.joint_maps[0], recorded(root)
    arm = joint_map.arm(joint_map.slots[0])
    state = frames[OBS_STATE][:1]
    (held,) = joint_map.arm_joints(state, OBS_STATE)
    far = held.clone()
    far[0, 0] += 1.5  # the base turned 86 deg away
    chunk = arm.pose(far).expand(4, -1).unsqueeze(0)  # (1 robot, 4 actions, 9)
    free, _, held_back = joint_map.reach(chunk, state)
    assert held_back == 0 and abs(free[0][0, 0, 0] - held[0, 0]) > 1.4, "one jump of the base"
    (bounded,), _, held_back = joint_map.reach(chunk, state, seconds=0.1)
    step = arm.speed * 0.1  # 0.315 rad for the UR5's base
    moves = torch.diff(torch.cat([held.unsqueeze(1), bounded.to(torch.float64)], dim=1), dim=1).abs()
    assert (moves <= step + 1e-6).all() and held_back == 4
    assert float(bounded[0, -1, 0] - held[0, 0]) == pytest.approx(4 * float(step[0]), abs=1e-5), "in steps"


@pytest.mark.parametrize("space", ["per_embodiment", "galr"])
def test_two_robots_of_different_arms_hands_and_rates_merge_train_and_each_gets_its_own_joints_back(
    tmp_path, space
):
    """A UR5 with an Inspire hand at 30 fps and a Panda with a umi gripper at 10 fps merge (the body: each
    wrist's pose), train one policy, and each robot's action comes back as its own arm's joints, in its own
    entries: a recorded frame through the preprocessor and back through the postprocessor is its action."""
    from test_policy import batch_of, make_policy, save_galr

    save_galr(tmp_path / "galr", ["umi", "inspire"])
    maps = []
    for robot, (arm, hand, fps) in ROBOTS.items():
        write_armed_dataset(tmp_path / robot, arm, hand, frames=3 * fps // 2, n_points=32, fps=fps, seed=fps)
        maps.append(f"{tmp_path / robot}={write_map(tmp_path / f'{robot}.yaml', arm, hand)}")
    merge = ["dataset", "merge", "--inputs", *(str(tmp_path / r) for r in ROBOTS), "--output",
             str(tmp_path / "merged"), "--galr", str(tmp_path / "galr"), "--joint-maps", *maps]  # fmt: skip
    assert cli.main(merge) == 0
    policy, pre, post, dataset = make_policy(tmp_path, "merged", action_space=space)
    assert dataset.meta.fps == 10
    assert [s.get_config().get("fps") for s in pre.steps if hasattr(s, "record_for_decode")] == [10]
    assert dataset.meta.features[OBS_STATE]["names"][:9] == [f"tool.{name}" for name in POSE_NAMES]
    loss, _ = policy.forward(pre(batch_of(dataset, [0, 5, 20, 40])))
    loss.backward()
    assert loss.isfinite()
    for robot, (arm, _, _) in ROBOTS.items():
        frames = recorded(tmp_path / robot)
        state, action = frames[OBS_STATE][:4].float(), frames[ACTION][:4].float()
        observation = {OBS_STATE: state, OBS_POINTCLOUD: torch.zeros(len(state), 3 * 32)}
        encoded = pre._forward(create_transition(observation=observation, action=action,
                                                 complementary_data={ROBOT_TYPE: robot}))  # fmt: skip
        back = post._forward(create_transition(action=encoded[TransitionKey.ACTION]))[TransitionKey.ACTION]
        spec = load_arm(arm)
        dof, chain = len(spec.joints), spec.chain()
        assert back.shape == action.shape
        error = pose_error(spec.wrist_pose(chain, back[:, :dof]), spec.wrist_pose(chain, action[:, :dof]))
        assert error[:, :3].norm(dim=-1).max() < 1e-3 and error[:, 3:].norm(dim=-1).max() < math.radians(0.5)
        assert (back[:, :dof] - action[:, :dof]).abs().max() < 0.05, robot  # a 7-DoF Panda may move its elbow
        if space == "per_embodiment":
            assert torch.allclose(back[:, dof:], action[:, dof:], atol=1e-4), robot


def test_arm_joints_recorded_in_degrees_are_refused_naming_the_entry_and_the_scale(tmp_path, capsys):
    write_armed_dataset(tmp_path / "ur5_deg", "panda", "umi", frames=8, n_points=16, arm_scale=DEGREE)
    maps = f"{tmp_path / 'ur5_deg'}={write_map(tmp_path / 'map.yaml', 'panda', 'umi')}"
    merge = ["dataset", "merge", "--inputs", str(tmp_path / "ur5_deg"), "--output", str(tmp_path / "out"),
             "--joint-maps", maps]  # fmt: skip
    assert cli.main(merge) != 0
    error = capsys.readouterr().err
    assert "'panda_joint1.pos'" in error and "in degrees" in error and "scale: 0.0174533" in error
    assert not (tmp_path / "out").exists()


def test_an_armed_map_that_leaves_an_entry_without_a_place_or_misses_a_joint_is_refused(tmp_path):
    names = [f"{j}.pos" for j in load_arm("ur5").joints] + ["left_jaw_joint"]
    spec_map = {"hand": "umi", "joints": {"left_jaw_joint": "left_jaw_joint"}, "arm": "ur5"}
    with pytest.raises(JointMapError, match=r"\['base_current'\] are neither an arm's nor a hand's joint"):
        JointMap.from_dict(spec_map).bind([*names, "base_current"], names)
    JointMap.from_dict({**spec_map, "drop": ["base_current"]}).bind([*names, "base_current"], names)
    with pytest.raises(JointMapError, match="joint 'wrist_3_joint' has no entry"):
        JointMap.from_dict(spec_map).bind(names[:5] + names[6:], names[:5] + names[6:])
    with pytest.raises(JointMapError, match="must name each joint of arm 'ur5' once"):
        JointMap.from_dict({**spec_map, "arm_joints": {names[0]: "shoulder_pan_joint"}}).bind(names, names)
    with pytest.raises(JointMapError, match="arm 'ur6': unknown arm 'ur6' .*did you mean 'ur5'"):
        JointMap.from_dict({**spec_map, "arm": "ur6"}).bind(names, names)


@pytest.mark.parametrize("space", ["per_embodiment", "galr"])
def test_the_floating_simulator_hands_demos_co_train_with_an_arm_and_the_simulator_gets_its_entries_back(
    tmp_path, space
):
    """The simulator's floating umi demos, read through `arm: floating`, and a UR5 with an Inspire hand
    share the wrist-pose body and merge; the simulator (a robot named by its hands) then gets its six wrist
    entries and jaw back from the policy's pose, exactly."""
    from test_policy import make_policy, rollout, save_galr

    from lerobot_opfa.datasets.synthetic import write_synthetic_dataset

    save_galr(tmp_path / "galr", ["umi", "inspire"])
    write_synthetic_dataset(tmp_path / "sim_umi", "umi", episodes=2, frames=12, n_points=32, fps=10)
    write_armed_dataset(tmp_path / "ur5_inspire", "ur5", "inspire", frames=12, n_points=32, fps=10)
    maps = [f"{tmp_path / 'sim_umi'}={write_map(tmp_path / 'sim.yaml', 'floating', 'umi')}",
            f"{tmp_path / 'ur5_inspire'}={write_map(tmp_path / 'ur5.yaml', 'ur5', 'inspire')}"]  # fmt: skip
    inputs = [str(tmp_path / "sim_umi"), str(tmp_path / "ur5_inspire")]
    merge = ["dataset", "merge", "--inputs", *inputs, "--output", str(tmp_path / "merged"), "--galr",
             str(tmp_path / "galr"), "--joint-maps", *maps]  # fmt: skip
    assert cli.main(merge) == 0
    policy, pre, post, _ = make_policy(tmp_path, "merged", action_space=space)
    frames = recorded(tmp_path / "sim_umi")
    state, action = frames[OBS_STATE][:4].float(), frames[ACTION][:4].float()
    observation = {OBS_STATE: state, OBS_POINTCLOUD: torch.zeros(len(state), 3 * 32)}
    encoded = pre._forward(create_transition(observation=observation, action=action,
                                             complementary_data={ROBOT_TYPE: "umi"}))  # fmt: skip
    back = post._forward(create_transition(action=encoded[TransitionKey.ACTION]))[TransitionKey.ACTION]
    assert torch.allclose(back[:, :6], action[:, :6], atol=1e-4)
    if space == "per_embodiment":
        assert torch.allclose(back, action, atol=1e-4)
    acted = rollout(policy, pre, post, "umi", torch.randn(32 * 3) * 0.05, steps=2)
    assert acted.shape == (2, 7) and acted.isfinite().all()


def test_lerobots_end_effector_entries_are_the_wrist_pose_with_no_arm_model():
    """A dataset in LeRobot's end-effector convention (`ee.x, ..., ee.wz` a rotation vector, as its
    kinematic processor steps write them, and `ee.gripper_pos`) maps onto the wrist pose directly."""
    names = ["ee.x", "ee.y", "ee.z", "ee.wx", "ee.wy", "ee.wz", "ee.gripper_pos"]
    gripper = {"ee.gripper_pos": {"joint": "left_jaw_joint", "scale": -0.00044, "offset": 0.044}}
    joint_map = JointMap.from_dict({"hand": "umi", "joints": gripper, "arm": "end_effector"}).bind(
        names, names
    )
    frames = torch.tensor([[0.2, -0.1, 0.15, 0.3, -2.0, 0.5, 40.0], [0.25, 0.0, 0.1, 0.0, 0.0, 0.0, 100.0]])
    body, (jaw,) = joint_map.split(frames.double(), ACTION)
    rotation = rotation_vector_matrix(frames[:, 3:6].double())
    assert torch.allclose(pose_matrix(body)[:, :3, :3], rotation, atol=1e-12)
    assert torch.allclose(body[:, :3], frames[:, :3].double()) and torch.allclose(
        jaw[:, 0], 0.044 - 0.00044 * frames[:, 6].double()
    )
    assert torch.allclose(joint_map.join(body, [jaw]), frames.double(), atol=1e-9)


def test_a_robot_without_an_arm_beside_one_with_an_arm_is_refused_saying_how_to_give_it_the_wrist_pose(
    tmp_path, capsys
):
    from lerobot_opfa.datasets.synthetic import write_synthetic_dataset

    write_synthetic_dataset(tmp_path / "sim_umi", "umi", episodes=1, frames=8, n_points=16)
    write_armed_dataset(tmp_path / "ur5_inspire", "ur5", "inspire", episodes=1, frames=8, n_points=16)
    maps = f"{tmp_path / 'ur5_inspire'}={write_map(tmp_path / 'ur5.yaml', 'ur5', 'inspire')}"
    merge = ["dataset", "merge", "--inputs", str(tmp_path / "sim_umi"), str(tmp_path / "ur5_inspire"),
             "--output", str(tmp_path / "merged"), "--joint-maps", maps]  # fmt: skip
    assert cli.main(merge) != 0
    error = capsys.readouterr().err
    assert f"{tmp_path / 'sim_umi'} names no arm" in error and "`floating` for the simulator's" in error
