"""Two hands on two wrists: `OpfaBimanualEnv`, a task one hand cannot do (`LiftTray`: lift a tray level by
its two handles) and its scripted expert, one single-hand expert per arm in step.

The arms are the single-hand scene's wrist carriage twice, named `left/...` (home at +y) and `right/...`
(home at -y), each carrying any registered hand; a left arm carries the right-hand model of its hand (the
models are right hands, and a left hand's policy entries are the right model's at the same joints).
Action and `agent_pos` share one layout, as a two-armed robot names its entries: the left wrist's pose and
the left hand's joints, then the right's (`state_names`)."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import mujoco
import numpy as np

from lerobot_opfa.datasets.joint_map import HANDS_SEPARATOR, SIDES, JointMap, arm_entries
from lerobot_opfa.envs.env import (
    POINTCLOUD_SOURCES,
    OpfaSimEnv,
    check_choice,
    observation_spaces,
    parse_cameras,
)
from lerobot_opfa.envs.experts import ScriptedExpert
from lerobot_opfa.envs.observation import SceneViews
from lerobot_opfa.envs.regions import REGIONS, parse_regions
from lerobot_opfa.envs.scene import (
    HOME,
    WRIST_JOINTS,
    WRIST_RANGE,
    Scene,
    base_spec,
    index_arm,
    mount_hand,
)
from lerobot_opfa.envs.tasks import (
    ENV_STATE_DIM,
    RISEN,
    TASKS,
    LiftBox,
    Placement,
    Task,
    _free_body_state,
    _geom,
)
from lerobot_opfa.hands.model import HandModel
from lerobot_opfa.hands.registry import load_hand

HOME_Y = 0.16
"""m: each wrist's home this far to its side of the table's centre line."""
SETTLE_STEPS = 20
TWO_HAND_OBS_TYPES = ("pointcloud", "state", "pointcloud_state")


def arm_homes() -> dict[str, np.ndarray]:
    return {
        side: HOME + [0.0, sign * HOME_Y, 0.0, 0.0, 0.0, 0.0]
        for side, sign in zip(SIDES, (1, -1), strict=True)
    }


@dataclass
class TwoArms:
    """A compiled two-armed scene: each arm's addresses, and what tasks read of the whole."""

    model: mujoco.MjModel
    arms: dict[str, Scene]

    @property
    def hand_geoms(self) -> np.ndarray:
        return np.concatenate([arm.hand_geoms for arm in self.arms.values()])


class LiftTray(Task):
    """Lift a tray by its two handles, both 6 cm up and each half level within 10 degrees. The tray is two
    halves on a hinge along its middle, each a plate with a handle (the `lift_box` box): a hand lifting
    one handle folds its half up about the hinge, or lifts the tray with the other half hanging, so one
    hand cannot do it (a rigid tray held by one handle was lifted level for a moment by one hand, the
    hand's grip torque enough for its 0.8 kg)."""

    name = "lift_tray"
    episode_steps = 130
    description = "lift the tray with both hands"
    object_body = "tray"
    halves = {"left": "tray", "right": "tray_right"}
    handle = LiftBox()
    handle_y = 0.15  # m, each handle's centre from the hinge, along the tray's y
    plate_half = (0.03, 0.075, 0.008)  # each half's plate, from the hinge to beyond its handle
    plate_mass = 0.1
    hinge_damping = 0.02
    lift_height, max_tilt = 0.06, np.radians(10.0)
    max_yaw = np.radians(5.0)

    def build(self, spec: mujoco.MjSpec) -> None:
        body = spec.worldbody.add_body(name=self.object_body, pos=[0, 0, 0])
        body.add_freejoint(name=self.object_body)
        right = body.add_body(name=self.halves["right"], pos=[0, 0, 0])
        right.add_joint(
            name="tray_hinge", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[1, 0, 0], damping=self.hinge_damping
        )
        size = [self.handle.half_width, self.handle.half_width, self.handle.half_height]
        for half, sign in ((body, 1), (right, -1)):
            _geom(
                half, [0.2, 0.45, 0.85, 1], type=mujoco.mjtGeom.mjGEOM_BOX, size=size,
                pos=[0, sign * self.handle_y, self.handle.half_height], mass=self.handle.mass,
            )  # fmt: skip
            _geom(
                half, [0.85, 0.85, 0.8, 1], type=mujoco.mjtGeom.mjGEOM_BOX, size=list(self.plate_half),
                pos=[0, sign * (self.plate_half[1] + 0.002), self.plate_half[2]], mass=self.plate_mass,
            )  # fmt: skip

    def bind(self, scene) -> None:
        model = scene.model
        self.qpos = model.jnt_qposadr[model.joint(self.object_body).id]
        self.hinge = model.jnt_qposadr[model.joint("tray_hinge").id]
        self.bodies = {side: model.body(name).id for side, name in self.halves.items()}

    def place(self, scene, data: mujoco.MjData, xy: np.ndarray, rng: np.random.Generator) -> Placement:
        yaw = float(rng.uniform(-self.max_yaw, self.max_yaw))
        data.qpos[self.qpos : self.qpos + 7] = [*xy, 0.0, np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]
        data.qpos[self.hinge] = 0.0
        return Placement(xy, yaw)

    def handles(self, placement: Placement) -> dict[str, np.ndarray]:
        """Each side's handle centre (x, y) on the table as placed (the left one at +y)."""
        c, s = np.cos(placement.yaw), np.sin(placement.yaw)
        return {
            side: placement.xy + sign * self.handle_y * np.array([-s, c])
            for side, sign in zip(SIDES, (1, -1), strict=True)
        }

    def env_state(self, scene, data: mujoco.MjData) -> np.ndarray:
        """The left half's pose (3 + 4), then the hinge angle in the articulation slot."""
        state = np.zeros(ENV_STATE_DIM)
        state[:7], state[-1] = _free_body_state(data, self.qpos), data.qpos[self.hinge]
        return state

    def tilts(self, data: mujoco.MjData) -> np.ndarray:
        """Radians between each half's up axis and the world's (left, right)."""
        return np.array([np.arccos(np.clip(data.xmat[self.bodies[side]][8], -1.0, 1.0)) for side in SIDES])

    def handle_rises(self, data: mujoco.MjData) -> np.ndarray:
        """How far each handle's centre (left, right) stands above where it rests on the table."""
        rises = []
        for side, sign in zip(SIDES, (1, -1), strict=True):
            body = self.bodies[side]
            local = np.array([0.0, sign * self.handle_y, self.handle.half_height])
            rises.append(
                data.xpos[body][2] + data.xmat[body].reshape(3, 3)[2] @ local - self.handle.half_height
            )
        return np.array(rises)

    def success(self, scene, data: mujoco.MjData) -> bool:
        level = self.tilts(data).max() <= self.max_tilt
        return bool(level and self.handle_rises(data).min() >= self.lift_height)

    def failure(self, states: np.ndarray) -> str:
        rise = states[:, 2].max() - states[0, 2]
        fold = np.degrees(np.abs(states[:, -1]).max())
        if rise < RISEN:
            return f"grasp: the tray rose {100 * rise:.0f} cm (folded up to {fold:.0f} deg at its hinge)"
        return f"lift: the tray rose {100 * rise:.0f} cm, folded up to {fold:.0f} deg at its hinge"


BIMANUAL_TASKS: dict[str, type[Task]] = {LiftTray.name: LiftTray}
ALL_TASKS: dict[str, type[Task]] = {**TASKS, **BIMANUAL_TASKS}
"""Every task by name: one hand's, then two hands'."""


def check_any_task(name: str | None) -> str:
    if name not in ALL_TASKS:
        raise ValueError(f"unknown task '{name}'; valid tasks: {', '.join(ALL_TASKS)}")
    return name


def task_hands(task: str, hand: str) -> list[str]:
    """The hands a task's `hand` names: one, or for a two-hand task one per side (`inspire+xhand`)."""
    if task in BIMANUAL_TASKS:
        return parse_hands(hand)
    if HANDS_SEPARATOR in str(hand):
        raise ValueError(
            f"{task} takes one hand, got two ('{hand}'); the two-hand tasks are {', '.join(BIMANUAL_TASKS)}"
        )
    return [hand]


def parse_hands(hands: str | list[str] | tuple[str, ...]) -> list[str]:
    """'inspire+xhand', 'inspire,xhand' or a pair -> [left hand, right hand]."""
    names = hands.replace(HANDS_SEPARATOR, ",").split(",") if isinstance(hands, str) else list(hands)
    names = [n.strip() for n in names if n.strip()]
    if len(names) != 2:
        raise ValueError(
            f"a two-armed scene takes two hands, left then right ('inspire+xhand'), got {hands!r}"
        )
    return names


class OpfaBimanualEnv(gym.Env):
    """A table-top task for two registered hands, one on each of two floating wrists (see the module)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        task: str = "lift_tray",
        hands: str | list[str] = "inspire+xhand",
        regions: str | list[str] = "all",
        obs_type: str = "pointcloud",
        pointcloud_source: str = "depth",
        n_points: int = 1024,
        depth_cameras: str | list[str] = "front",
        fps: int = 20,
        render_mode: str = "rgb_array",
        render_width: int = 320,
        render_height: int = 240,
    ) -> None:
        self.task = BIMANUAL_TASKS[check_choice("two-hand task", task, list(BIMANUAL_TASKS))]()
        self.hand_models = dict(zip(SIDES, map(load_hand, parse_hands(hands)), strict=True))
        self.regions = parse_regions(regions)
        self.obs_type = check_choice("obs_type", obs_type, TWO_HAND_OBS_TYPES)
        self.pointcloud_source = check_choice("pointcloud source", pointcloud_source, POINTCLOUD_SOURCES)
        self.depth_cameras = parse_cameras(depth_cameras)
        self.n_points, self.render_mode = n_points, render_mode
        self.render_size = (render_height, render_width)
        self.metadata = {**self.metadata, "render_fps": fps}
        spec = base_spec()
        self.task.build(spec)
        tools = {side: mount_hand(spec, hand, f"{side}/") for side, hand in self.hand_models.items()}
        model = spec.compile()
        arms = {side: index_arm(model, self.hand_models[side], tools[side], f"{side}/") for side in SIDES}
        self.scene = TwoArms(model, arms)
        self.task.bind(self.scene)
        self.model, self.data = model, mujoco.MjData(model)
        self.n_substeps = max(1, round(1.0 / (fps * model.opt.timestep)))
        self.homes = arm_homes()
        low, high = [], []
        for hand in self.hand_models.values():
            low += [*WRIST_RANGE[:, 0], *hand.lower.double().cpu().numpy()]
            high += [*WRIST_RANGE[:, 1], *hand.upper.double().cpu().numpy()]
        self.action_space = gym.spaces.Box(np.float32(low), np.float32(high), dtype=np.float32)
        self.observation_space = gym.spaces.Dict(observation_spaces(self.obs_type, len(low), n_points))
        self.views = SceneViews(model, pointcloud_source, n_points, self.depth_cameras, self.render_size)
        self.placement: Placement | None = None
        self.region: str | None = None

    @property
    def task_description(self) -> str:
        return self.task.description

    @property
    def joint_map(self) -> JointMap:
        """How its state and action hold the wrists and the hands: `left_wrist_x`, ..., `left_<joint>`,
        ..., then the right arm's."""
        specs = {side: hand.spec for side, hand in self.hand_models.items()}
        names = arm_entries(specs, list(WRIST_JOINTS))
        return JointMap.named_after_arms(specs, names, names)

    @property
    def state_names(self) -> list[str]:
        return list(self.joint_map.state_names)

    @property
    def action_names(self) -> list[str]:
        return self.state_names

    @property
    def hand_name(self) -> str:
        """The robot by its hands, left first (`inspire+xhand`): what a policy's pipeline names it by."""
        return HANDS_SEPARATOR.join(hand.name for hand in self.hand_models.values())

    def command(self, targets: np.ndarray) -> np.ndarray:
        """The action that takes the wrists and hands to `targets` (what the scripted expert gives)."""
        return targets

    @property
    def hands_by_side(self) -> dict[str, HandModel]:
        return dict(self.hand_models)

    def hand_readings(self) -> dict[str, np.ndarray]:
        """Each side's hand joints as the simulator holds them now."""
        return {side: self.data.qpos[arm.hand_qpos] for side, arm in self.scene.arms.items()}

    def arm(self, side: str) -> ArmView:
        """One arm as a single-hand expert reads an env."""
        handle = self.task.handles(self.placement)[side]
        return ArmView(
            hand_model=self.hand_models[side],
            hand_open=self.hand_models[side].pose("open").double().cpu().numpy(),
            scene=self.scene.arms[side],
            task=self.task.handle,
            placement=Placement(handle, self.placement.yaw),
            data=self.data,
            home=self.homes[side],
        )

    def observation(self) -> dict[str, np.ndarray]:
        qpos = self.data.qpos
        arms = self.scene.arms.values()
        obs = {"agent_pos": np.concatenate([qpos[np.r_[a.wrist_qpos, a.hand_qpos]] for a in arms])}
        if "pointcloud" in self.obs_type:
            obs["pointcloud"] = self.views.point_cloud(self.data, self.np_random)
        if "state" in self.obs_type:
            obs["environment_state"] = self.task.env_state(self.scene, self.data)
        return obs

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        self.region = (options or {}).get("region") or self.regions[
            self.np_random.integers(len(self.regions))
        ]
        x, y = REGIONS[self.region].sample(self.np_random)
        self.placement = self.task.place(self.scene, self.data, np.array([x, y / 4]), self.np_random)
        for side, arm in self.scene.arms.items():
            hand = self.hand_models[side]
            self.data.qpos[arm.wrist_qpos] = self.homes[side]
            self.data.qpos[arm.chain_qpos] = hand.expand(hand.pose("open")[None])[0].double().cpu().numpy()
            self.data.ctrl[arm.ctrl] = np.concatenate(
                [self.homes[side], hand.pose("open").double().cpu().numpy()]
            )
        mujoco.mj_forward(self.model, self.data)
        mujoco.mj_step(self.model, self.data, SETTLE_STEPS)
        return self.observation(), {"is_success": False, "region": self.region}

    def step(self, action: np.ndarray):
        action = np.clip(np.asarray(action, dtype=np.float64), self.action_space.low, self.action_space.high)
        self.data.ctrl[np.concatenate([arm.ctrl for arm in self.scene.arms.values()])] = action
        mujoco.mj_step(self.model, self.data, self.n_substeps)
        success = self.task.success(self.scene, self.data)
        return self.observation(), float(success), success, False, {"is_success": success}

    def render(self) -> np.ndarray:
        return self.views.picture(self.data)

    def close(self) -> None:
        self.views.close()


@dataclass
class ArmView:
    """What a single-hand scripted expert reads of its env, for one arm of a two-armed one: the arm's hand
    and addresses, its handle as the object to lift, where it stands at home."""

    hand_model: HandModel
    hand_open: np.ndarray
    scene: Scene
    task: Task
    placement: Placement
    data: mujoco.MjData
    home: np.ndarray


class BimanualExpert:
    """One single-hand expert per arm, each lifting its handle, their waypoints timed alike so both hands
    close, and lift, together."""

    def __init__(self, env: OpfaBimanualEnv, rng: np.random.Generator) -> None:
        self.experts = [ScriptedExpert(env.arm(side), rng) for side in SIDES]
        steps = np.max([[w.steps for w in e.plan] for e in self.experts], axis=0)
        for expert in self.experts:
            for waypoint, n in zip(expert.plan, steps, strict=True):
                waypoint.steps = int(n)
            expert.schedule = np.cumsum(steps)

    def act(self) -> np.ndarray:
        return np.concatenate([expert.act() for expert in self.experts])

    @property
    def done(self) -> bool:
        return all(expert.done for expert in self.experts)


def sim_env(
    task: str, hand: str, regions: str | list[str] = "all", **options
) -> OpfaSimEnv | OpfaBimanualEnv:
    """The env of a task: two arms for a two-hand task (`hand` names both, `inspire+xhand`), else one."""
    if task in BIMANUAL_TASKS:
        if options.pop("control", "joints") != "joints":
            raise ValueError(f"two-hand task '{task}' takes control joints")
        options.pop("rgb_cameras", None)
        return OpfaBimanualEnv(task, hand, regions, **options)
    (one,) = task_hands(task, hand)
    return OpfaSimEnv(task, one, regions, **options)


def scripted_expert(
    env: OpfaSimEnv | OpfaBimanualEnv, rng: np.random.Generator
) -> ScriptedExpert | BimanualExpert:
    return (BimanualExpert if isinstance(env, OpfaBimanualEnv) else ScriptedExpert)(env, rng)
