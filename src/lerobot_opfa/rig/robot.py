"""`--robot.type=opfa_sim`: the benchmark's MuJoCo scene as a LeRobot `Robot`, seen as a real rig is: each
wrist and hand joint as `<name>.pos`, depth cameras as (H, W, 1) millimetres (uint16, as RealSense's
`read_depth`), RGB cameras as (H, W, 3) uint8, and a calibration file of the depth cameras in the format
`--policy.cameras` reads. `lerobot-record`, `lerobot-rollout` and this package's processors meet it as they
would meet hardware.

LeRobot's loops have no reset hook: a person resets a real scene in the reset phase. The simulated scene
resets itself (the task's objects placed as the gym env places them, seed + episode index): with
`episode_time_s` (the recorder's `--dataset.episode_time_s`, and `--dataset.reset_time_s=0`) at the first
observation that long after the episode's first, since LeRobot's loops start no step after it; with
`auto_reset` (a `base` rollout) when the task succeeds or runs out of steps. Each episode's outcome goes to
a JSON-lines log, since `lerobot-rollout` reports none.

The scene moves only when an action arrives, so a loop slower than its fps does not make control harder,
it makes episodes shorter in steps. Success counts within the task's `episode_steps`, the budget
`lerobot-eval` gives, and an episode that ends with fewer steps is reported: its length in seconds did not
cover the task's budget at the loop's achieved rate.
"""

from __future__ import annotations

import json
import logging
import time
import weakref
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from lerobot.robots.config import RobotConfig
from lerobot.robots.robot import Robot

from lerobot_opfa.arms.spec import load_arm
from lerobot_opfa.envs.env import OpfaSimEnv, check_arm, parse_cameras
from lerobot_opfa.envs.observation import ColourCameras, DepthPointCloud
from lerobot_opfa.envs.regions import parse_regions
from lerobot_opfa.envs.tasks import check_task, task_hands
from lerobot_opfa.flags import FlagError, flag
from lerobot_opfa.hands.registry import load_spec
from lerobot_opfa.pointclouds import DepthRig

logger = logging.getLogger(__name__)

LIVE_RIGS: weakref.WeakValueDictionary[str, OpfaSimRobot] = weakref.WeakValueDictionary()
"""Connected rigs by id, for the expert teleoperator, which drives the scene it reads."""

POSITION = ".pos"
SLACK_S = 0.01
"""Past `episode_time_s`, the time a loop takes from its last step's end to its next observation: no
episode's step starts that late, and saving an episode takes longer."""


@RobotConfig.register_subclass("opfa_sim")
@dataclass(kw_only=True)
class OpfaSimRobotConfig(RobotConfig):
    id: str | None = "opfa_sim"
    hand: str = "umi"  # a built-in hand name or a spec.yaml path; a two-hand task's: left+right
    arm: str | None = None  # the arm the hand is on (`lerobot-opfa arms list`); None: the floating wrist
    task: str = "lift"
    regions: str = "all"
    hide_object: bool = False  # no camera shows the task's objects (demos for a blind control)
    seed: int = 0
    fps: int = 20
    depth_cameras: str = "front"  # comma-separated: front, left, right (`<name>_depth` features)
    rgb_cameras: str = ""  # comma-separated, the same cameras in colour (`<name>_rgb` features)
    width: int = 128
    height: int = 96
    episode_time_s: float | None = None
    """The recorder's episode length: the scene resets at the first observation this long after the
    episode's first (LeRobot's record and episodic rollout loops start no step after that time)."""
    auto_reset: bool = False
    """Reset when the task succeeds or runs out of steps (for `lerobot-rollout --strategy.type=base`)."""
    episodes_log: Path | None = None
    """Where each episode's outcome is appended (default: `<calibration_dir>/<id>_episodes.jsonl`)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        with flag("robot.task"):
            check_task(self.task)
        with flag("robot.hand"):
            hands = [load_spec(hand).name for hand in task_hands(self.task, self.hand)]
        with flag("robot.arm"):
            check_arm(self.arm, self.task, hands, "joints")
            if self.arm is not None:
                load_arm(self.arm)
        with flag("robot.regions"):
            parse_regions(self.regions)
        with flag("robot.depth_cameras"):
            parse_cameras(self.depth_cameras)
        with flag("robot.rgb_cameras"):
            if self.rgb_cameras:
                parse_cameras(self.rgb_cameras)
        if (self.episode_time_s is not None and self.episode_time_s <= 0) or self.fps < 1:
            raise FlagError(("robot",), "opfa_sim: episode_time_s and fps must be positive")


class OpfaSimRobot(Robot):
    config_class = OpfaSimRobotConfig
    name = "opfa_sim"

    def __init__(self, config: OpfaSimRobotConfig):
        super().__init__(config)
        self.config = config
        self.env = OpfaSimEnv(
            config.task,
            config.hand,
            config.regions,
            obs_type="state",
            fps=config.fps,
            arm=config.arm,
            hide_object=config.hide_object,
        )
        # what LeRobot records as the dataset's robot_type: the hand(s), on an arm `<arm>_<hand>`
        self.name = self.robot_type = self.env.robot_type
        self.joint_names = list(self.env.state_names)
        self.depth_names = parse_cameras(config.depth_cameras)
        self.rgb_names = parse_cameras(config.rgb_cameras) if config.rgb_cameras else []
        self.cameras = {f"{c}_depth": c for c in self.depth_names} | {f"{c}_rgb": c for c in self.rgb_names}
        """The rendered cameras by feature name (LeRobot sizes its image writers by their count)."""
        self.episodes_log = config.episodes_log or self.calibration_dir / f"{self.id}_episodes.jsonl"
        self.cameras_file = self.calibration_dir / f"{self.id}_cameras.yaml"
        self._connected = False
        self.episode, self.steps, self.success = 0, 0, False
        self.outcomes: list[dict] = []
        self._episode_start: float | None = None
        self._observed_at: float | None = None

    # --- features --------------------------------------------------------------------------------------
    @cached_property
    def observation_features(self) -> dict:
        shape = (self.config.height, self.config.width)
        return (
            {f"{n}{POSITION}": float for n in self.joint_names}
            | {f"{c}_depth": (*shape, 1) for c in self.depth_names}
            | {f"{c}_rgb": (*shape, 3) for c in self.rgb_names}
        )

    @cached_property
    def action_features(self) -> dict:
        return {f"{n}{POSITION}": float for n in self.joint_names}

    # --- lifecycle -------------------------------------------------------------------------------------
    @property
    def is_connected(self) -> bool:
        return self._connected

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        """Nothing to calibrate: the scene's cameras are known exactly (see `cameras_file`)."""

    def configure(self) -> None:
        """Nothing to configure."""

    def connect(self, calibrate: bool = True) -> None:
        if self._connected:
            raise RuntimeError(f"{self} is already connected")
        self.depth = DepthPointCloud(
            self.env.model, 1, self.depth_names, self.config.width, self.config.height
        )
        self.colour = ColourCameras(self.env.model, self.rgb_names, self.config.width, self.config.height)
        self._reset_scene()
        self.cameras_file.parent.mkdir(parents=True, exist_ok=True)
        self.cameras_file.write_text(yaml.safe_dump(self.depth_calibration().to_dict(), sort_keys=False))
        self.episodes_log.parent.mkdir(parents=True, exist_ok=True)
        self._connected = True
        LIVE_RIGS[self.id] = self
        logger.info(
            f"{self}: cameras' calibration in {self.cameras_file}, episodes logged to {self.episodes_log}"
        )

    def depth_calibration(self) -> DepthRig:
        """The depth cameras as `--policy.cameras` takes them, keyed as `lerobot-record` names them."""
        cameras = self.depth.pinhole_cameras(self.env.data)
        return DepthRig(
            {f"observation.images.{c}_depth": cam for c, cam in zip(self.depth_names, cameras, strict=True)}
        )

    def disconnect(self) -> None:
        if not self._connected:
            return
        if self.steps:
            self._finish("disconnect")
        self._connected = False
        LIVE_RIGS.pop(self.id, None)
        self.depth.close()
        self.colour.close()
        failed = [o["episode"] for o in self.outcomes if not o["success"]]
        if failed:
            logger.info(
                f"{self}: episodes {failed} failed; to keep the successful ones of a recorded dataset: "
                f"lerobot-edit-dataset --repo_id REPO --root ROOT --operation.type delete_episodes "
                f'--operation.episode_indices "{failed}"'
            )

    # --- control ---------------------------------------------------------------------------------------
    def get_observation(self) -> dict[str, Any]:
        if not self._connected:
            raise RuntimeError(f"{self} is not connected")
        start, length = self._episode_start, self.config.episode_time_s
        if start is not None and length and time.perf_counter() - start >= length + SLACK_S:
            self._finish("time")
        self._observed_at = time.perf_counter()
        if self._episode_start is None and self.episode > 0:  # a loop's first observation of a new scene
            self._episode_start = self._observed_at
        state = self.env.observation()["agent_pos"]
        observation = {f"{n}{POSITION}": float(v) for n, v in zip(self.joint_names, state, strict=True)}
        for name, depth in zip(self.depth_names, self.depth.depth_images(self.env.data), strict=True):
            observation[f"{name}_depth"] = np.round(depth * 1000).astype(np.uint16)[..., None]
        for name, image in self.colour.images(self.env.data).items():
            observation[f"{name}_rgb"] = image
        return observation

    def send_action(self, action: dict[str, Any]) -> dict[str, Any]:
        if not self._connected:
            raise RuntimeError(f"{self} is not connected")
        missing = [k for k in self.action_features if k not in action]
        if missing:
            raise ValueError(f"{self}: the action lacks {missing} (it has {', '.join(action)})")
        vector = np.array([float(action[k]) for k in self.action_features])
        if self._episode_start is None:  # the first scene's clock starts at the observation its first step
            self._episode_start = self._observed_at  # answers, not at those an engine takes while it sets up
        _, _, _, truncated, info = self.env.step(vector)
        self.steps += 1
        self.success = self.success or (
            self.steps <= self.env.task.episode_steps and bool(info["is_success"])
        )
        if self.config.auto_reset and (
            self.success or truncated or self.steps >= self.env.task.episode_steps
        ):
            self._finish("success" if self.success else "steps")
        return {k: action[k] for k in self.action_features}

    # --- episodes --------------------------------------------------------------------------------------
    def _reset_scene(self) -> None:
        self.env.reset(seed=self.config.seed + self.episode)
        self.steps, self.success, self._episode_start = 0, False, None

    def _finish(self, ended: str) -> None:
        """Logs the episode's outcome, then places the next episode's objects."""
        outcome = {"episode": self.episode, "seed": self.config.seed + self.episode,
                   "region": self.env.region, "hand": self.env.hand_name, "task": self.env.task.name,
                   "success": self.success, "steps": self.steps, "ended": ended}  # fmt: skip
        self.outcomes.append(outcome)
        budget = self.env.task.episode_steps
        if ended == "time" and self.steps < budget:
            logger.warning(
                f"{self}: episode {self.episode} ended after {self.steps} of the task's {budget} steps "
                f"(the loop ran at {self.steps / self.config.episode_time_s:.1f} Hz, the scene's is "
                f"{self.config.fps} Hz); a longer episode_time_s gives the policy lerobot-eval's budget"
            )
        with self.episodes_log.open("a") as log:
            log.write(json.dumps(outcome) + "\n")
        self.episode += 1
        self._reset_scene()
