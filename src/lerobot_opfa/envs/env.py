"""`OpfaSimEnv`: a gymnasium env of one task for one hand on one arm, or two on two, with LeRobot's
observation keys."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import gymnasium as gym
import mujoco
import numpy as np

from lerobot_opfa.datasets.joint_map import HANDS_SEPARATOR, SIDES, JointMap, sided
from lerobot_opfa.envs import DEFAULT_FPS
from lerobot_opfa.envs.control import (
    EE_ACTION_NAMES,
    EE_STATE_NAMES,
    ArmJoints,
    EndEffectorDeltas,
    check_control,
)
from lerobot_opfa.envs.observation import ColourCameras, SceneViews
from lerobot_opfa.envs.regions import REGIONS, parse_regions
from lerobot_opfa.envs.scene import (
    DEPTH_CAMERAS,
    HOME,
    WRIST_JOINTS,
    WRIST_RANGE,
    Arm,
    Scene,
    base_spec,
    build_scene,
    hide_objects,
)
from lerobot_opfa.envs.tasks import ENV_STATE_DIM, Placement, Task, make_task, task_hands
from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.registry import load_hand

logger = logging.getLogger(__name__)

OBS_TYPES = ("pointcloud", "state", "pointcloud_state", "rgb", "pointcloud_rgb")
POINTCLOUD_SOURCES = ("depth", "geometry")
SETTLE_STEPS = 20  # physics steps after reset so objects come to rest
HOME_Y = 0.16
"""m: with two arms, each wrist's home this far to its side of the table's centre line (left at +y)."""


def check_choice(kind: str, value: str, valid: tuple[str, ...] | list[str]) -> str:
    if value not in valid:
        raise ValueError(f"unknown {kind} '{value}'; valid {kind}s: {', '.join(valid)}")
    return value


def check_arm(arm: str | None, task: str, hands: list[str], control: str) -> None:
    """An arm carries the hand of a one-hand task, under `joints` control."""
    if arm is None:
        return
    if len(hands) != 1:
        raise ValueError(f"an arm carries one hand; {task} takes {len(hands)}: leave the arm out")
    if control != "joints":
        raise ValueError(f"an arm's robot acts in its joints: leave control {control} out, or the arm")


def parse_cameras(cameras: str | list[str]) -> list[str]:
    """'front', 'front,left' or a list -> validated camera names (the scene's depth cameras, which also
    take colour pictures)."""
    names = [c.strip() for c in cameras.split(",")] if isinstance(cameras, str) else list(cameras)
    return [check_choice("depth camera", name, list(DEPTH_CAMERAS)) for name in names]


def observation_spaces(obs_type: str, state_width: int, n_points: int) -> dict[str, gym.spaces.Box]:
    """The numeric observations: `agent_pos`, and by `obs_type` the point cloud and the task's object
    state."""
    spaces = {"agent_pos": gym.spaces.Box(-np.inf, np.inf, (state_width,), np.float64)}
    if "pointcloud" in obs_type:
        spaces["pointcloud"] = gym.spaces.Box(-np.inf, np.inf, (n_points * 3,), np.float32)
    if "state" in obs_type:
        spaces["environment_state"] = gym.spaces.Box(-np.inf, np.inf, (ENV_STATE_DIM,), np.float64)
    return spaces


def arm_homes(sides: tuple[str | None, ...]) -> dict[str | None, np.ndarray]:
    """Each arm's wrist pose at home: one arm at `HOME`, two each `HOME_Y` to its side."""
    if sides == (None,):
        return {None: HOME}
    return {
        side: HOME + [0.0, sign * HOME_Y, 0.0, 0.0, 0.0, 0.0]
        for side, sign in zip(SIDES, (1, -1), strict=True)
    }


def arm_entry(side: str | None, name: str) -> str:
    """An entry of one arm: its own name on a one-armed robot, `<side>_<name>` on a two-armed one."""
    return name if side is None else sided(side, name)


def as_array(values) -> np.ndarray:
    """A hand model's tensor as the simulator's float64 array."""
    return values.double().cpu().numpy()


@dataclass
class ArmView:
    """What one arm's scripted expert reads of its env: the arm's hand and addresses, its part of the
    task as placed, where it stands at home."""

    hand_model: HandModel
    hand_open: np.ndarray
    arm: Arm
    scene: Scene
    task: Task
    placement: Placement
    data: mujoco.MjData
    home: np.ndarray


class OpfaSimEnv(gym.Env):
    """A table-top task for any registered hand on a floating wrist, or for two (a two-hand task,
    `hand="inspire+xhand"`: left, then right), each on a wrist of its own.

    Action and `agent_pos` share one layout, per arm (left first): the wrist's tool-frame pose (x, y, z in
    metres, then yaw, pitch, roll in radians; the approach axis points down at zero angles) followed by
    the hand's actuated joints in its spec's order; with two arms each entry is named `<side>_<name>`, as
    LeRobot's two-armed robots name theirs (`state_names`, `joint_map`). A left arm carries the right-hand
    model of its hand (the models are right hands, and a left hand's policy entries are the right model's
    at the same joints). Actions are absolute position targets. `pointcloud` is (n_points * 3,)
    world-frame xyz, flattened so LeRobot datasets built from it can be merged; `environment_state` is the
    task's object state (`tasks.ENV_STATE_DIM`); `pixels` (obs types with `rgb`) holds each of
    `rgb_cameras` as `<name>_rgb`, (camera_height, camera_width, 3) uint8, as the rig records them.
    With `control="ee_delta"` (a gripper on each arm), action and `agent_pos` hold other entries
    (`envs.control`), arm by arm. With `arm` (a one-hand task), the hand is on that arm (`arms.spec`):
    action and `agent_pos` hold the arm's joints, as its model names them, then the hand's
    (`control.ArmJoints`). With `hide_object`, no camera or cloud shows the task's objects (a control:
    the same task for a policy blind to the object); `environment_state` and success still read them.
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
        fps: int = DEFAULT_FPS,
        render_mode: str = "rgb_array",
        render_width: int = 320,
        render_height: int = 240,
        control: str = "joints",
        arm: str | None = None,
        hide_object: bool = False,
    ) -> None:
        self.task = make_task(task)
        names = task_hands(task, hand)
        sides = (None,) if len(names) == 1 else SIDES
        self.hand_models: dict[str | None, HandModel] = dict(zip(sides, map(load_hand, names), strict=True))
        for model in self.hand_models.values():
            check_control(control, model.name, model.dof)
        check_arm(arm, task, names, control)
        self.homes = arm_homes(sides)
        self.arm_joints = None if arm is None else ArmJoints(arm, self.hand_models[None], self.homes[None])
        self.ee = (
            {side: EndEffectorDeltas(hand, self.homes[side]) for side, hand in self.hand_models.items()}
            if control == "ee_delta"
            else None
        )
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
        self.scene = build_scene(spec, self.hand_models)
        self.task.bind(self.scene)
        if hide_object:
            hide_objects(self.scene)
        self.model = self.scene.model
        self.data = mujoco.MjData(self.model)
        self.n_substeps = max(1, round(1.0 / (fps * self.model.opt.timestep)))
        self.ctrl_index = np.concatenate([arm.ctrl for arm in self.scene.arms.values()])
        self.hand_open = {side: as_array(hand.pose("open")) for side, hand in self.hand_models.items()}

        low = np.concatenate([[*WRIST_RANGE[:, 0], *as_array(h.lower)] for h in self.hand_models.values()])
        high = np.concatenate([[*WRIST_RANGE[:, 1], *as_array(h.upper)] for h in self.hand_models.values()])
        self.target_space = gym.spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        """The wrists' and the hands' targets (what `joints` control takes)."""
        if self.arm_joints is not None:
            self.action_space = self.arm_joints.action_space
        elif self.ee is None:
            self.action_space = self.target_space
        else:
            spaces = [ee.action_space for ee in self.ee.values()]
            self.action_space = gym.spaces.Box(
                np.concatenate([s.low for s in spaces]),
                np.concatenate([s.high for s in spaces]),
                dtype=np.float32,
            )
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
        if self.arm_joints is not None:
            return [*self.arm_joints.names, *self.hand_models[None].joint_names]
        per_arm = {
            side: EE_STATE_NAMES if self.ee is not None else (*WRIST_JOINTS, *hand.joint_names)
            for side, hand in self.hand_models.items()
        }
        return [arm_entry(side, name) for side, names in per_arm.items() for name in names]

    @property
    def action_names(self) -> list[str]:
        if self.ee is None:
            return self.state_names
        return [arm_entry(side, name) for side in self.hand_models for name in EE_ACTION_NAMES]

    @property
    def joint_map(self) -> JointMap | None:
        """How its state and action hold the wrists and the hands, as a recorded robot's map says it
        (none under `ee_delta`: its entries are read through the map a policy was trained with)."""
        if self.ee is not None:
            return None
        names = self.state_names
        specs = {side: hand.spec for side, hand in self.hand_models.items()}
        if None in specs:
            arm = None if self.arm_joints is None else self.arm_joints.ref
            return JointMap.named_after(specs[None], names, names, arm=arm)
        return JointMap.named_after_arms(specs, names, names)

    @property
    def robot_type(self) -> str:
        """What its datasets record as `robot_type`: the robot by its hands (`hand_name`), on an arm
        `<arm>_<hand>` (`ur5_inspire`)."""
        if self.arm_joints is None:
            return self.hand_name
        return f"{self.arm_joints.body.spec.name}_{self.hand_name}"

    @property
    def hand_name(self) -> str:
        """The robot by its hands, left first (`inspire`; `inspire+xhand`): what a policy's pipeline names it
        by."""
        return HANDS_SEPARATOR.join(hand.name for hand in self.hand_models.values())

    def hand_readings(self) -> dict[str | None, np.ndarray]:
        """Each side's hand joints as the simulator holds them now (one arm: side None)."""
        return {side: self.data.qpos[arm.hand_qpos] for side, arm in self.scene.arms.items()}

    def arm(self, side: str | None) -> ArmView:
        """One arm as a single-hand scripted expert reads an env."""
        task, placement = self.task.for_arm(side, self.placement)
        return ArmView(
            hand_model=self.hand_models[side],
            hand_open=self.hand_open[side],
            arm=self.scene.arms[side],
            scene=self.scene,
            task=task,
            placement=placement,
            data=self.data,
            home=self.homes[side],
        )

    def command(self, targets: np.ndarray) -> np.ndarray:
        """The action of this env's control that takes the wrists and hands to `targets` (what the
        scripted experts give)."""
        if self.arm_joints is not None:
            return self.arm_joints.command(targets)
        if self.ee is None:
            return targets
        cuts = np.cumsum([len(WRIST_JOINTS) + hand.dof for hand in self.hand_models.values()])[:-1]
        return np.concatenate(
            [ee.command(t) for ee, t in zip(self.ee.values(), np.split(targets, cuts), strict=True)]
        )

    def observation(self) -> dict[str, np.ndarray]:
        qpos = self.data.qpos
        arms = self.scene.arms
        if self.arm_joints is not None:
            arm = arms[None]
            state = [self.arm_joints.state(qpos[arm.wrist_qpos], qpos[arm.hand_qpos])]
        elif self.ee is None:
            state = [qpos[np.r_[arm.wrist_qpos, arm.hand_qpos]] for arm in arms.values()]
        else:
            state = [
                ee.state(qpos[arm.wrist_qpos], self.data.qvel[arm.wrist_qvel], qpos[arm.hand_qpos][0])
                for ee, arm in zip(self.ee.values(), arms.values(), strict=True)
            ]
        obs = {"agent_pos": np.concatenate(state)}
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
        for side, arm in self.scene.arms.items():
            hand = self.hand_models[side]
            self.data.qpos[arm.wrist_qpos] = self.homes[side]
            self.data.qpos[arm.chain_qpos] = as_array(hand.expand(hand.pose("open")[None])[0])
            self.data.ctrl[arm.ctrl] = np.concatenate([self.homes[side], self.hand_open[side]])
        mujoco.mj_forward(self.model, self.data)
        mujoco.mj_step(self.model, self.data, SETTLE_STEPS)
        for ee in (self.ee or {}).values():
            ee.reset()
        if self.arm_joints is not None:
            self.arm_joints.reset()
        return self.observation(), {"is_success": False, "region": self.region}

    def step(self, action: np.ndarray):
        action = np.clip(np.asarray(action, dtype=np.float64), self.action_space.low, self.action_space.high)
        if self.ee is not None:
            steps = np.split(action, len(self.ee))
            targets = np.concatenate([ee.targets(a) for ee, a in zip(self.ee.values(), steps, strict=True)])
            action = np.clip(targets, self.target_space.low, self.target_space.high)
        if self.arm_joints is not None:
            targets = self.arm_joints.targets(action, self.data.qpos[self.scene.arms[None].wrist_qpos])
            action = np.clip(targets, self.target_space.low, self.target_space.high)
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
