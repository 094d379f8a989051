"""The MuJoCo benchmark's envs: every hand in every task scene, success detection, point clouds, names."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np
import pytest
from conftest import BUILTIN_HANDS

from lerobot_opfa.envs.config import OpfaEnvConfig
from lerobot_opfa.envs.env import OpfaSimEnv
from lerobot_opfa.envs.experts import SQUEEZE, ScriptedExpert
from lerobot_opfa.envs.observation import DEPTH_QUALITY
from lerobot_opfa.envs.regions import REGIONS, parse_regions
from lerobot_opfa.envs.tasks import ONE_HAND_TASKS, TASKS
from lerobot_opfa.flags import FlagError
from lerobot_opfa.pointclouds import WORKSPACE_HIGH, WORKSPACE_LOW

TASK_NAMES = ONE_HAND_TASKS


def test_the_table_has_at_least_nine_regions():
    assert len(REGIONS) >= 9


@pytest.mark.parametrize("hand", BUILTIN_HANDS)
def test_every_hand_steps_in_every_task(hand):
    """Each scene compiles with the hand attached and random actions keep the state finite."""
    for task in TASK_NAMES:
        env = OpfaSimEnv(task, hand, obs_type="pointcloud_state", pointcloud_source="geometry", n_points=64)
        obs, info = env.reset(seed=1)
        assert env.action_space.shape == obs["agent_pos"].shape == (6 + env.hand_models[None].dof,)
        for _ in range(4):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            assert all(np.all(np.isfinite(v)) for v in obs.values()), (hand, task)
            assert isinstance(info["is_success"], bool)
        env.close()


def test_user_hand_loads_into_a_scene(user_allegro_spec):
    env = OpfaSimEnv("press_button", str(user_allegro_spec), obs_type="state")
    obs, _ = env.reset(seed=0)
    assert obs["agent_pos"].shape == (22,)
    env.step(env.action_space.sample())


@pytest.mark.parametrize("task", TASK_NAMES)
def test_success_detection(task):
    """A scripted success is detected from the simulator state, and the hand touched the task's object on
    the way; holding still is neither."""
    env = OpfaSimEnv(task, "umi", obs_type="state")
    env.reset(seed=3)
    expert, success, touched = ScriptedExpert(env, np.random.default_rng(3)), False, False
    while not (expert.done or success):
        _, _, success, _, info = env.step(expert.act())
        touched = touched or env.task.touched(env.scene, env.data)
    assert success and info["is_success"] and touched

    obs, _ = env.reset(seed=3)
    hold = obs["agent_pos"].copy()
    for _ in range(40):
        _, _, terminated, _, info = env.step(hold)
        assert not terminated and not info["is_success"] and not env.task.touched(env.scene, env.data)
    env.close()


def test_pick_place_needs_release():
    """Carrying the banana over the plate without letting go is not a success."""
    env = OpfaSimEnv("pick_place", "umi", obs_type="state")
    env.reset(seed=3)
    expert = ScriptedExpert(env, np.random.default_rng(3))
    (arm,) = expert.arms
    arm.plan[-3].closure = arm.plan[-2].closure = arm.plan[-1].closure = SQUEEZE  # never open
    while not expert.done:
        _, _, terminated, _, _ = env.step(expert.act())
        assert not terminated
    env.close()


def test_depth_point_cloud_sees_the_object():
    env = OpfaSimEnv("lift", "umi", obs_type="pointcloud_state", n_points=256)
    obs, _ = env.reset(seed=0)
    cloud = obs["pointcloud"].reshape(-1, 3)
    assert obs["pointcloud"].shape == (768,) and obs["pointcloud"].dtype == np.float32
    assert np.all(cloud > WORKSPACE_LOW) and np.all(cloud < WORKSPACE_HIGH)
    can = obs["environment_state"][:3]
    assert np.sum(np.linalg.norm(cloud[:, :2] - can[:2], axis=1) < 0.04) >= 20
    quality = env.model.vis.quality  # the depth context's cheap settings were not left on the model
    assert {k: getattr(quality, k) for k in DEPTH_QUALITY} != DEPTH_QUALITY
    frame = env.render()  # a picture context bigger than the depth image: offwidth/offheight restored
    assert frame.dtype == np.uint8 and frame.shape == (240, 320, 3)
    env.close()


def test_regions_place_objects_inside():
    env = OpfaSimEnv("lift", "umi", regions="far_left", obs_type="state")
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        region = REGIONS["far_left"]
        x, y = obs["environment_state"][:2]
        assert info["region"] == "far_left"
        assert region.x[0] <= x <= region.x[1] and region.y[0] <= y <= region.y[1]
    assert parse_regions("all") == list(REGIONS)
    assert parse_regions("near_left, mid_center") == ["near_left", "mid_center"]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"task": "juggle"},
            "unknown task 'juggle'; valid tasks: lift, lift_box, pick_place, press_button, pull_drawer",
        ),
        ({"hand": "hook"}, "unknown hand 'hook': not a built-in (ability, allegro"),
        ({"regions": "moon"}, "unknown region(s) ['moon']; valid regions: all, near_right"),
        ({"obs_type": "pixels"}, "unknown obs_type 'pixels'; valid obs_types: pointcloud, state"),
        (
            {"depth_cameras": "front,top"},
            "unknown depth camera 'top'; valid depth cameras: front, left, right",
        ),
    ],
)
def test_bad_names_list_the_valid_ones(kwargs, message):
    with pytest.raises(ValueError) as err:
        OpfaSimEnv(**kwargs)
    assert message in str(err.value)
    with pytest.raises(FlagError) as err:  # what LeRobot's command lines print as one line
        OpfaEnvConfig(**kwargs)
    assert message in str(err.value)


def test_gym_ids_and_config():
    env = gym.make("opfa/press_button-v0", hand="umi", obs_type="state")
    assert env.spec.max_episode_steps == TASKS["press_button"].episode_steps
    env.reset(seed=0)
    env.close()
    cfg = OpfaEnvConfig(task="pull_drawer", hand="leap", obs_type="pointcloud_state", n_points=32)
    assert cfg.type == "opfa" and cfg.gym_id == "opfa/pull_drawer-v0"
    assert cfg.features["action"].shape == cfg.features["agent_pos"].shape == (22,)
    assert cfg.features["pointcloud"].shape == (96,) and cfg.features["environment_state"].shape == (11,)
    assert cfg.features_map["pointcloud"] == "observation.pointcloud"
    vec = cfg.create_envs(n_envs=2)["opfa"][0]
    obs, _ = vec.reset(seed=[0, 1])
    assert obs["pointcloud"].shape == (2, 96)
    vec.close()


@pytest.mark.parametrize("task", ["lift", "pull_drawer"])
def test_a_blind_env_shows_no_object_and_plays_the_same_task(task):
    """`hide_object`: no colour camera, depth cloud or geometry cloud sees the task's objects; the physics,
    the object state and the expert's success are those of the seen scene."""
    from lerobot_opfa.envs.demos import expert_episode

    seen, blind = (
        OpfaSimEnv(task, "umi", "mid_center", obs_type="pointcloud_rgb", n_points=512, hide_object=hide)
        for hide in (False, True)
    )
    shown, hidden = (env.reset(seed=2)[0] for env in (seen, blind))
    objects = [g for g in range(seen.model.ngeom) if blind.model.geom_group[g] != seen.model.geom_group[g]]
    assert objects and not set(objects) & set(seen.scene.hand_geoms.tolist())
    near = seen.task.env_state(seen.scene, seen.data)[:3]
    for obs, expected in ((shown, True), (hidden, False)):
        cloud = obs["pointcloud"].reshape(-1, 3)
        assert (np.linalg.norm(cloud - near, axis=1) < 0.06).any() == expected
    assert np.abs(shown["pixels"]["front_rgb"].astype(int) - hidden["pixels"]["front_rgb"]).max() > 100
    for env in (seen, blind):
        env.close()
    states = []
    for hide in (False, True):
        env = OpfaSimEnv(
            task, "umi", "mid_center", obs_type="pointcloud_state", pointcloud_source="geometry",
            n_points=256, hide_object=hide,
        )  # fmt: skip
        frames, success = expert_episode(env, seed=2, region="mid_center", hold=0)
        assert success
        cloud = frames[0]["observation.pointcloud"].reshape(-1, 3)
        assert (np.linalg.norm(cloud - near, axis=1) < 0.06).any() != hide
        states.append(np.stack([f["observation.environment_state"] for f in frames]))
        env.close()
    assert np.array_equal(*states)


def test_demos_hold_the_success_for_a_few_frames():
    """Demos go on past their first success for HOLD_STEPS frames, the expert holding its last target, so
    chunks that start in the final approach exist in training; success is still decided in time."""
    from lerobot_opfa.envs.demos import HOLD_STEPS, expert_episode

    env = OpfaSimEnv(
        "press_button", "umi", obs_type="pointcloud_state", pointcloud_source="geometry", n_points=32
    )
    until, ok = expert_episode(env, seed=3, region="mid_center", hold=0)
    held, held_ok = expert_episode(env, seed=3, region="mid_center")
    assert ok and held_ok and len(held) == len(until) + HOLD_STEPS
    for a, b in zip(until, held, strict=False):
        assert np.array_equal(a["observation.state"], b["observation.state"])
    last = np.stack([f["action"] for f in held[-HOLD_STEPS:]])
    assert np.ptp(last[:, 2]) < 0.005, "the wrist holds the press height"
    assert env.task.success(env.scene, env.data), "still pressed after the hold"
    env.close()


def test_the_env_shows_the_rigs_colour_pictures_of_the_same_scene(tmp_path):
    """A policy trained on the rig's recorded `front_rgb` frames is evaluated on the env's `pixels`: both
    render the same camera through one renderer, so the same scene state gives the same picture."""
    from lerobot_opfa.rig.robot import OpfaSimRobot, OpfaSimRobotConfig

    config = OpfaSimRobotConfig(
        hand="umi", task="press_button", rgb_cameras="front", calibration_dir=tmp_path
    )
    robot = OpfaSimRobot(config)
    robot.connect()
    recorded = robot.get_observation()["front_rgb"]
    env = OpfaSimEnv("press_button", "umi", obs_type="rgb")
    env.reset(seed=0)
    env.data.qpos[:], env.data.qvel[:] = robot.env.data.qpos, robot.env.data.qvel
    import mujoco

    mujoco.mj_forward(env.model, env.data)
    pixels = env.observation()["pixels"]
    robot.disconnect()
    env.close()
    assert list(pixels) == ["front_rgb"] and pixels["front_rgb"].dtype == np.uint8
    assert pixels["front_rgb"].shape == recorded.shape == (96, 128, 3)
    assert np.array_equal(pixels["front_rgb"], recorded)
    assert recorded.std() > 10  # a picture, not a blank frame
    cfg = OpfaEnvConfig(task="lift", hand="umi", obs_type="pointcloud_rgb", rgb_cameras="front,left")
    assert cfg.features_map["pixels/left_rgb"] == "observation.images.left_rgb"
    assert cfg.features["pixels/front_rgb"].shape == (96, 128, 3)


def test_contact_does_not_push_a_joint_past_its_stop(monkeypatch):
    """The drawer's handle pushes Shadow's thumb against its 12 deg stop: the simulated hand holds the stop
    (its recorded reading stays within 1 % of the range), and a simulator that lets it through (MuJoCo's
    default, softer limits) makes the demo writer refuse the episode in one line rather than write demos
    that training refuses."""
    from lerobot_opfa.envs.demos import expert_episode
    from lerobot_opfa.hands import mujoco_model

    env = OpfaSimEnv("pull_drawer", "shadow", obs_type="pointcloud_state", n_points=32)
    frames, ok = expert_episode(env, seed=0, region="mid_center")
    hand = env.hand_models[None]
    lower, upper = hand.lower.numpy(), hand.upper.numpy()
    readings = np.stack([frame["observation.state"][-hand.dof :] for frame in frames])
    assert ok and (np.maximum(lower - readings, readings - upper) / (upper - lower)).max() < 0.01
    env.close()
    monkeypatch.setattr(mujoco_model, "LIMIT_SOLREF", [0.02, 1.0])
    env = OpfaSimEnv("pull_drawer", "shadow", obs_type="pointcloud_state", n_points=32)
    with pytest.raises(ValueError, match=r"seed 0\).*'thumb_mcp_abd'.*past its stop"):
        expert_episode(env, seed=0, region="mid_center")
    env.close()
