"""`OpfaSimEnv`: a gymnasium env for one (task, hand) pair with LeRobot's observation keys."""

from __future__ import annotations

import logging

import gymnasium as gym
import mujoco
import numpy as np

from lerobot_opfa.envs.control import EE_ACTION_NAMES, EE_STATE_NAMES, EndEffectorDeltas, check_control
from lerobot_opfa.envs.observation import ColourCameras, SceneViews
from lerobot_opfa.envs.regions import REGIONS, parse_regions
from lerobot_opfa.envs.scene import (
    DEPTH_CAMERAS,
    HOME,
    WRIST_JOINTS,
    WRIST_RANGE,
    attach_hand,
    base_spec,
)
from lerobot_opfa.envs.tasks import ENV_STATE_DIM, Placement, make_task
from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.registry import load_hand

logger = logging.getLogger(__name__)

OBS_TYPES = ("pointcloud", "state", "pointcloud_state", "rgb", "pointcloud_rgb")
POINTCLOUD_SOURCES = ("depth", "geometry")
SETTLE_STEPS = 20  # physics steps after reset so objects come to rest


def check_choice(kind: str, value: str, valid: tuple[str, ...] | list[str]) -> str:
    if value not in valid:
        raise ValueError(f"unknown {kind} '{value}'; valid {kind}s: {', '.join(valid)}")
    return value


def parse_cameras(cameras: str | list[str]) -> list[str]:
    """'front', 'front,left' or a list -> validated camera names (the scene's depth cameras, which also
    take colour pictures)."""
    names = [c.strip() for c in cameras.split(",")] if isinstance(cameras, str) else list(cameras)
    return [check_choice("depth camera", name, list(DEPTH_CAMERAS)) for name in names]


def observation_spaces(obs_type: str, state_width: int, n_points: int) -> dict[str, gym.spaces.Box]:
    """The numeric observations both scenes give: `agent_pos`, and by `obs_type` the point cloud and the
    task's object state."""
    spaces = {"agent_pos": gym.spaces.Box(-np.inf, np.inf, (state_width,), np.float64)}
    if "pointcloud" in obs_type:
        spaces["pointcloud"] = gym.spaces.Box(-np.inf, np.inf, (n_points * 3,), np.float32)
    if "state" in obs_type:
        spaces["environment_state"] = gym.spaces.Box(-np.inf, np.inf, (ENV_STATE_DIM,), np.float64)
    return spaces


class OpfaSimEnv(gym.Env):
    """A table-top task for any registered hand on a floating wrist.

    Action and `agent_pos` share one layout: the wrist's tool-frame pose (x, y, z in metres, then yaw,
    pitch, roll in radians; the approach axis points down at zero angles) followed by the hand's actuated
    joints in its spec's order. Actions are absolute position targets. `pointcloud` is (n_points * 3,)
    world-frame xyz, flattened so LeRobot datasets built from it can be merged; `environment_state` is the
    task's object state (`tasks.ENV_STATE_DIM`); `pixels` (obs types with `rgb`) holds each of
    `rgb_cameras` as `<name>_rgb`, (camera_height, camera_width, 3) uint8, as the rig records them.
    With `control="ee_delta"` (a gripper), action and `agent_pos` hold other entries (`envs.control`).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        task: str = "lift",
        hand: str = "leap",
        regions: str | list[str] = "all",
        obs_type: str = "pointcloud",
        pointcloud_source: str = "depth",
        n_points: int = 1024,
        depth_cameras: str | list[str] = "front",
        rgb_cameras: str | list[str] = "front",
        camera_width: int = 128,
        camera_height: int = 96,
        fps: int = 20,
        render_mode: str = "rgb_array",
        render_width: int = 320,
        render_height: int = 240,
        control: str = "joints",
    ) -> None:
        self.task = make_task(task)
        self.hand_model = load_hand(hand)
        check_control(control, self.hand_model.name, self.hand_model.dof)
        self.ee = EndEffectorDeltas(self.hand_model) if control == "ee_delta" else None
        self.regions = parse_regions(regions)
        self.obs_type = check_choice("obs_type", obs_type, OBS_TYPES)
        self.pointcloud_source = check_choice("pointcloud source", pointcloud_source, POINTCLOUD_SOURCES)
        self.depth_cameras = parse_cameras(depth_cameras)
        self.rgb_cameras = parse_cameras(rgb_cameras)
        self.camera_size = (camera_height, camera_width)
        self.n_points, self.render_mode = n_points, render_mode
        self.render_size = (render_height, render_width)
        self.metadata = {**self.metadata, "render_fps": fps}

        spec = base_spec()
        self.task.build(spec)
        self.scene = attach_hand(spec, self.hand_model)
        self.task.bind(self.scene)
        self.model = self.scene.model
        self.data = mujoco.MjData(self.model)
        self.n_substeps = max(1, round(1.0 / (fps * self.model.opt.timestep)))
        self.wrist_qvel = np.array([self.model.jnt_dofadr[self.model.joint(j).id] for j in WRIST_JOINTS])
        self.ctrl_index = self.scene.ctrl
        self.hand_open = self.hand_model.pose("open").double().cpu().numpy()
        self.hand_open_all = (
            self.hand_model.expand(self.hand_model.pose("open")[None])[0].double().cpu().numpy()
        )

        low = np.concatenate([WRIST_RANGE[:, 0], self.hand_model.lower.double().cpu().numpy()])
        high = np.concatenate([WRIST_RANGE[:, 1], self.hand_model.upper.double().cpu().numpy()])
        self.target_space = gym.spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        """The wrist's and the hand's targets (what `joints` control takes)."""
        self.action_space = self.target_space if self.ee is None else self.ee.action_space
        spaces = observation_spaces(self.obs_type, len(self.state_names), n_points)
        if "rgb" in self.obs_type:
            picture = gym.spaces.Box(0, 255, (*self.camera_size, 3), np.uint8)
            spaces["pixels"] = gym.spaces.Dict({f"{c}_rgb": picture for c in self.rgb_cameras})
        self.observation_space = gym.spaces.Dict(spaces)

        self.views = SceneViews(self.model, pointcloud_source, n_points, self.depth_cameras, self.render_size)
        self._colour: ColourCameras | None = None
        self.placement: Placement | None = None
        self.region: str | None = None

    @property
    def task_description(self) -> str:
        """The language task LeRobot's eval loop passes to policies."""
        return self.task.description

    @property
    def state_names(self) -> list[str]:
        if self.ee is not None:
            return list(EE_STATE_NAMES)
        return list(WRIST_JOINTS) + list(self.hand_model.joint_names)

    @property
    def action_names(self) -> list[str]:
        return self.state_names if self.ee is None else list(EE_ACTION_NAMES)

    @property
    def hand_name(self) -> str:
        return self.hand_model.name

    @property
    def hands_by_side(self) -> dict[str | None, HandModel]:
        """The hand, by side (none: one hand)."""
        return {None: self.hand_model}

    def hand_readings(self) -> dict[str | None, np.ndarray]:
        """The hand's joints as the simulator holds them now (by side: none, one hand)."""
        return {None: self.data.qpos[self.scene.hand_qpos]}

    def command(self, targets: np.ndarray) -> np.ndarray:
        """The action of this env's control that takes the wrist and hand to `targets` (what the scripted
        experts give)."""
        return targets if self.ee is None else self.ee.command(targets)

    def observation(self) -> dict[str, np.ndarray]:
        wrist, hand = self.data.qpos[self.scene.wrist_qpos], self.data.qpos[self.scene.hand_qpos]
        if self.ee is None:
            obs = {"agent_pos": np.concatenate([wrist, hand])}
        else:
            obs = {"agent_pos": self.ee.state(wrist, self.data.qvel[self.wrist_qvel], hand[0])}
        if "pointcloud" in self.obs_type:
            obs["pointcloud"] = self.views.point_cloud(self.data, self.np_random)
        if "state" in self.obs_type:
            obs["environment_state"] = self.task.env_state(self.scene, self.data)
        if "rgb" in self.obs_type:
            if self._colour is None:
                height, width = self.camera_size
                self._colour = ColourCameras(self.model, self.rgb_cameras, width, height)
            obs["pixels"] = {f"{c}_rgb": image for c, image in self._colour.images(self.data).items()}
        return obs

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        self.region = (options or {}).get("region") or self.regions[
            self.np_random.integers(len(self.regions))
        ]
        xy = REGIONS[self.region].sample(self.np_random)
        self.placement = self.task.place(self.scene, self.data, xy, self.np_random)
        self.data.qpos[self.scene.wrist_qpos] = HOME
        self.data.qpos[self.scene.chain_qpos] = self.hand_open_all
        self.data.ctrl[self.ctrl_index] = np.concatenate([HOME, self.hand_open])
        mujoco.mj_forward(self.model, self.data)
        mujoco.mj_step(self.model, self.data, SETTLE_STEPS)
        if self.ee is not None:
            self.ee.reset()
        return self.observation(), {"is_success": False, "region": self.region}

    def step(self, action: np.ndarray):
        action = np.clip(np.asarray(action, dtype=np.float64), self.action_space.low, self.action_space.high)
        if self.ee is not None:
            action = np.clip(self.ee.targets(action), self.target_space.low, self.target_space.high)
        self.data.ctrl[self.ctrl_index] = action
        mujoco.mj_step(self.model, self.data, self.n_substeps)
        if self.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number:
            logger.warning("simulation became unstable (bad qacc); MuJoCo reset the state")
        success = self.task.success(self.scene, self.data)
        return self.observation(), float(success), success, False, {"is_success": success}

    def render(self) -> np.ndarray:
        return self.views.picture(self.data)

    def close(self) -> None:
        self.views.close()
        if self._colour is not None:
            self._colour.close()
            self._colour = None
