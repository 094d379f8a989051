"""The `opfa` env type for LeRobot (`--env.type=opfa`) and its gymnasium ids (`opfa/<task>-v0`): the
LeRobot adapter on top of the simulator (`env`, `tasks`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
from lerobot.configs import FeatureType, PolicyFeature, parser
from lerobot.envs.configs import EnvConfig
from lerobot.processor import EnvTransition, PolicyProcessorPipeline, ProcessorStep, TransitionKey
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE

from lerobot_opfa import checkpoint_files
from lerobot_opfa.arms.spec import load_arm
from lerobot_opfa.checkpoint_files import POSTPROCESSOR, PREPROCESSOR
from lerobot_opfa.datasets.joint_map import HANDS_SEPARATOR
from lerobot_opfa.envs import DEFAULT_FPS
from lerobot_opfa.envs.control import EE_ACTION_NAMES, EE_STATE_NAMES, check_control
from lerobot_opfa.envs.env import (
    OBS_TYPES,
    POINTCLOUD_SOURCES,
    check_arm,
    check_choice,
    parse_cameras,
)
from lerobot_opfa.envs.regions import parse_regions
from lerobot_opfa.envs.scene import WRIST_JOINTS
from lerobot_opfa.envs.tasks import ENV_STATE_DIM, TASKS, check_task, task_hands
from lerobot_opfa.features import OBS_POINTCLOUD, ROBOT_TYPE
from lerobot_opfa.flags import flag
from lerobot_opfa.hands.bundle import carried_hand
from lerobot_opfa.hands.registry import load_spec

ENCODE_STEP, DECODE_STEP = "opfa_encode_joints", "opfa_decode_joints"
"""The registry names of the steps that read a robot's entries and give its action entries back."""


def gym_id(task: str) -> str:
    return f"opfa/{task}-v0"


for _task in TASKS.values():
    if gym_id(_task.name) not in gym.registry:
        gym.register(
            id=gym_id(_task.name),
            entry_point="lerobot_opfa.envs.env:OpfaSimEnv",
            max_episode_steps=_task.episode_steps,
            kwargs={"task": _task.name},
        )


def converted_action_width(policy_path: str | None) -> int | None:
    """The action width of the local checkpoint at `policy_path` (what `--policy.path` names, read as
    LeRobot's own configs read it, `parser.get_path_arg`: the env config is parsed before the policy is
    loaded) if it is a stock policy given joint-space processors by `policy convert-io` (its actions are
    body + z, not the env's joints), else None."""
    config = checkpoint_files.read(policy_path, "config.json")
    if config is None or config.get("type") == "opfa":
        return None
    if not any(
        s.get("registry_name") == DECODE_STEP for s in checkpoint_files.steps(policy_path, POSTPROCESSOR)
    ):
        return None
    return int(config["output_features"][ACTION]["shape"][0])


def trained_state_names(policy_path: str | None) -> list[list[str]]:
    """The state entries of each robot the checkpoint at `policy_path` was trained on (none known: [])."""
    steps = [
        s for s in checkpoint_files.steps(policy_path, PREPROCESSOR) if s.get("registry_name") == ENCODE_STEP
    ]
    return [list(m["state_names"]) for step in steps for m in step.get("config", {}).get("joint_maps", [])]


def check_control_against(control: str, policy_path: str | None) -> None:
    """A control whose entries are not those of any robot the checkpoint at `policy_path` was trained on is
    the flag's mistake: said here, not as a width the policy's preprocessor cannot read."""
    trained = trained_state_names(policy_path)
    end_effector = [names == list(EE_STATE_NAMES) for names in trained]
    if control == "ee_delta" and trained and not any(end_effector):
        raise ValueError(
            f"ee_delta, but the policy at {policy_path} was trained on robots of the wrist pose and joints "
            f"({', '.join(trained[0][:3])}, ...): leave --env.control at joints"
        )
    if control == "joints" and trained and all(end_effector):
        raise ValueError(
            f"joints, but the policy at {policy_path} was trained on the ee_delta robot's entries "
            f"({', '.join(EE_STATE_NAMES[:3])}, ...): --env.control=ee_delta"
        )


def check_arm_against(state_names: list[str] | None, policy_path: str | None) -> None:
    """An env on an arm whose entries are not those of a robot the checkpoint at `policy_path` was trained
    on is refused: the policy would read its joints as another robot's (the floating wrist's six entries,
    another arm's) without a word."""
    trained = trained_state_names(policy_path)
    if state_names is None or not trained or state_names in trained:
        return
    raise ValueError(
        f"the policy at {policy_path} was trained on robots of entries "
        f"{'; '.join(', '.join(names[:3]) + ', ...' for names in trained)}, none of them this arm's "
        f"({', '.join(state_names[:3])}, ...): record demos on this arm (`sim demos --arm`) and train on "
        "them, or leave --env.arm out"
    )


@EnvConfig.register_subclass("opfa")
@dataclass
class OpfaEnvConfig(EnvConfig):
    """A task of the benchmark with one hand, or two (`lift_tray`); see `OpfaSimEnv` for the observation
    and action layouts."""

    task: str | None = "lift"
    hand: str = "leap"
    """A built-in hand's name, a spec.yaml path, or the name of a user hand the checkpoint at `--policy.path`
    carries; two-hand tasks: left+right."""
    regions: str = "all"  # comma-separated region names (`lerobot-opfa sim regions`), or "all"
    obs_type: str = "pointcloud"  # pointcloud | state | pointcloud_state | rgb | pointcloud_rgb
    pointcloud_source: str = "depth"  # depth (simulated cameras) | geometry (sampled, faster)
    n_points: int = 1024
    depth_cameras: str = "front"  # comma-separated: front, left, right (one render each per step)
    rgb_cameras: str = "front"  # with rgb obs types: colour cameras, `observation.images.<name>_rgb`
    camera_width: int = 128  # of the colour cameras (the rig's default size)
    camera_height: int = 96
    fps: int = DEFAULT_FPS
    episode_length: int | None = None  # steps; None: the task's default
    control: str = "joints"
    """`joints` (absolute wrist pose and hand joints) or `ee_delta` (a gripper: tool steps and a grasp
    command; `envs.control`). Under `ee_delta` the env is a robot of its own entries, read through the
    policy's joint map."""
    arm: str | None = None
    """The arm the hand is on (`lerobot-opfa arms list`, or an arm spec path; one-hand tasks): state and
    action are the arm's joints, then the hand's, as `sim demos --arm` records them. None: the floating
    wrist."""
    hide_object: bool = False
    """No camera or cloud shows the task's objects: the control condition of a policy blind to the object
    (train it on demos recorded the same way, `--robot.hide_object`)."""
    policy_action_width: int | None = None
    """The action width of a policy whose postprocessor gives this env its joints, when it differs (a stock
    policy in GaLR space: body + z). LeRobot's lerobot-eval builds even a pretrained policy's action
    output at the env's declared action width (policies/factory.make_policy), so the env declares this one;
    for a local checkpoint at `--policy.path` it is read from there (`converted_action_width`)."""
    render_width: int = 320
    render_height: int = 240
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        with flag("env.task"):
            check_task(self.task)
        policy_path = parser.get_path_arg("policy")
        hands = self.hand.split(HANDS_SEPARATOR)
        states = [path for path in checkpoint_files.state_files(policy_path) if path.is_file()]
        self.hand = HANDS_SEPARATOR.join(carried_hand(hand, states) for hand in hands)
        with flag("env.regions"):
            parse_regions(self.regions)
        with flag("env.obs_type"):
            check_choice("obs_type", self.obs_type, OBS_TYPES)
        with flag("env.pointcloud_source"):
            check_choice("pointcloud source", self.pointcloud_source, POINTCLOUD_SOURCES)
        with flag("env.depth_cameras"):
            parse_cameras(self.depth_cameras)
        with flag("env.rgb_cameras"):
            parse_cameras(self.rgb_cameras)
        with flag("env.hand"):
            specs = [load_spec(hand) for hand in task_hands(self.task, self.hand)]
        with flag("env.control"):
            for spec in specs:
                check_control(self.control, spec.name, len(spec.joints))
            check_control_against(self.control, policy_path)
        with flag("env.arm"):
            check_arm(self.arm, self.task, [spec.name for spec in specs], self.control)
            check_arm_against(self.state_names, policy_path)
        if self.control == "ee_delta":
            state, action = len(specs) * len(EE_STATE_NAMES), len(specs) * len(EE_ACTION_NAMES)
        elif self.arm is not None:
            state = action = len(self.state_names)
        else:
            state = action = sum(len(WRIST_JOINTS) + len(spec.joints) for spec in specs)
        if self.policy_action_width is not None and self.policy_action_width < 1:
            raise ValueError(f"--env.policy_action_width: a positive width, not {self.policy_action_width}")
        converted = converted_action_width(policy_path)
        if None not in (converted, self.policy_action_width) and converted != self.policy_action_width:
            with flag("env.policy_action_width"):
                raise ValueError(
                    f"{self.policy_action_width}, but the policy at {policy_path} acts {converted} wide (its "
                    "body + z): leave the flag out, and the width is read from the checkpoint"
                )
        action = self.policy_action_width or converted or action
        self.features = {ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(action,))}
        self.features["agent_pos"] = PolicyFeature(type=FeatureType.STATE, shape=(state,))
        self.features_map = {ACTION: ACTION, "agent_pos": OBS_STATE}
        if "pointcloud" in self.obs_type:
            self.features["pointcloud"] = PolicyFeature(type=FeatureType.STATE, shape=(3 * self.n_points,))
            self.features_map["pointcloud"] = OBS_POINTCLOUD
        if "state" in self.obs_type:
            self.features["environment_state"] = PolicyFeature(type=FeatureType.ENV, shape=(ENV_STATE_DIM,))
            self.features_map["environment_state"] = OBS_ENV_STATE
        if "rgb" in self.obs_type:
            for camera in parse_cameras(self.rgb_cameras):
                key = f"pixels/{camera}_rgb"
                self.features[key] = PolicyFeature(
                    type=FeatureType.VISUAL, shape=(self.camera_height, self.camera_width, 3)
                )
                self.features_map[key] = f"{OBS_IMAGES}.{camera}_rgb"

    def get_env_processors(self) -> tuple[PolicyProcessorPipeline, PolicyProcessorPipeline]:
        """Gives each frame the env's `robot_type`, as LeRobot gives a robot's: its hands' names, under
        which the policy reads it in their spec order and units, as it reads the `opfa_sim` rig, and picks
        the right embodiment even when two of its hands have the same joint count. Under `ee_delta` its
        entries are others: it says no type, and its frames go through the joint map the policy was trained
        with."""
        steps = [] if self.control == "ee_delta" else [RobotTypeStep(self.robot_type)]
        return PolicyProcessorPipeline(steps=steps), PolicyProcessorPipeline(steps=[])

    @property
    def robot_type(self) -> str:
        """The env's `robot_type`, as its demos record it (`OpfaSimEnv.robot_type`): its hands, on an arm
        `<arm>_<hand>`."""
        return self.hand_name if self.arm is None else f"{load_arm(self.arm).name}_{self.hand_name}"

    @property
    def state_names(self) -> list[str] | None:
        """The env's state entries on an arm (the arm's joints, then the hand's); None without one."""
        if self.arm is None:
            return None
        return [*load_arm(self.arm).joints, *load_spec(self.hand).actuated_joints]

    @property
    def hand_name(self) -> str:
        """The robot the frames come from, by its hands' names (`inspire`; `inspire+xhand`, left first)."""
        return HANDS_SEPARATOR.join(load_spec(hand).name for hand in task_hands(self.task, self.hand))

    @property
    def package_name(self) -> str:
        return __name__

    @property
    def gym_id(self) -> str:
        return gym_id(check_task(self.task))

    @property
    def gym_kwargs(self) -> dict:
        steps = self.episode_length or TASKS[self.task].episode_steps
        return {
            "hand": self.hand,
            "regions": self.regions,
            "obs_type": self.obs_type,
            "pointcloud_source": self.pointcloud_source,
            "n_points": self.n_points,
            "depth_cameras": self.depth_cameras,
            "rgb_cameras": self.rgb_cameras,
            "camera_width": self.camera_width,
            "camera_height": self.camera_height,
            "fps": self.fps,
            "render_width": self.render_width,
            "render_height": self.render_height,
            "max_episode_steps": steps,
            "control": self.control,
            "arm": self.arm,
            "hide_object": self.hide_object,
        }


@dataclass
class RobotTypeStep(ProcessorStep):
    """Adds the env's `robot_type` to every frame's complementary data, where LeRobot puts a robot's."""

    robot_type: str = ""

    def __call__(self, transition: EnvTransition) -> EnvTransition:
        complementary = dict(transition.get(TransitionKey.COMPLEMENTARY_DATA) or {})
        return {
            **transition,
            TransitionKey.COMPLEMENTARY_DATA: {**complementary, ROBOT_TYPE: self.robot_type},
        }

    def transform_features(self, features):
        return features
