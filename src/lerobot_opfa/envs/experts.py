"""Scripted experts: wrist waypoints in the hand's tool frame plus the spec's open and grasp poses.

Because the wrist is driven in the tool frame (see `toolframe`), the same waypoints serve every hand;
per hand only the tool frame's reach enters (how far the hand sticks out past its grasp centre). Every
episode draws its own waypoint offsets, yaw, timing and per-step action noise, so demonstrations vary."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_opfa.envs.env import OpfaSimEnv
from lerobot_opfa.envs.scene import HOME, tool_to_world
from lerobot_opfa.envs.tasks import Lift, PickPlace, PressButton, PullDrawer

# Hands close this far past the spec's grasp pose (clipped to the limits), so the servos keep squeezing an
# object that stops the fingers short of the pose; grippers close to their limit (their grasp poses are
# set for larger objects than these tasks').
SQUEEZE = 1.4
POSITION_NOISE = 0.004  # m, per waypoint
ACTION_NOISE = 0.001  # m, per step on the wrist position
CLEARANCE = 0.004  # m, between the hand and the table when reaching down
LIFT = 0.12  # m, approach from and retreat to this far above a grasp

# (task, hand) pairs left out of the benchmark's targets, with the reason (measured by bench_sim.py).
EXCLUDED_PAIRS: dict[tuple[str, str], str] = {}


@dataclass
class Waypoint:
    """Reach the tool pose `pose` (x, y, z, yaw) and the hand joints `hand` over `steps` steps."""

    pose: np.ndarray
    hand: np.ndarray
    steps: int


class ScriptedExpert:
    """Plans one episode from the state after `env.reset` and returns an action per step."""

    def __init__(self, env: OpfaSimEnv, rng: np.random.Generator) -> None:
        self.env, self.rng = env, rng
        hand = env.hand_model
        self.open = env.hand_open
        self.grasp = hand.pose("grasp").double().cpu().numpy()
        lower, upper = hand.lower.double().cpu().numpy(), hand.upper.double().cpu().numpy()
        if hand.spec.kind == "gripper":
            self.closed = np.where(
                self.grasp > self.open, upper, np.where(self.grasp < self.open, lower, self.grasp)
            )
        else:
            self.closed = np.clip(self.open + SQUEEZE * (self.grasp - self.open), lower, upper)
        self.tool = env.scene.tool
        self.start = Waypoint(np.array([*HOME[:3], HOME[3]]), self.open, 1)
        self.plan = self._plan()
        self.schedule = np.cumsum([w.steps for w in self.plan])
        self.t = 0

    def _jitter(self, xyz: np.ndarray) -> np.ndarray:
        return xyz + self.rng.normal(0.0, POSITION_NOISE, 3)

    def _steps(self, n: int) -> int:
        return max(2, int(round(n * self.rng.uniform(0.85, 1.15))))

    def _grasp_height(self, height: float, closure: float = 0.0) -> float:
        """The tool's height for grasping at `height`, high enough that the hand, `closure` of the way from
        open to grasp, clears the table."""
        return max(height, self.tool.reach_at(closure) + CLEARANCE)

    @staticmethod
    def _axis_yaw(angle: float) -> float:
        """Wrist yaw pointing the tool's x axis along a horizontal axis at `angle`, in [-pi/2, pi/2)."""
        return (angle + np.pi / 2) % np.pi - np.pi / 2

    def _grasp_plan(self, xy: np.ndarray, height: float, yaw: float) -> tuple[list[Waypoint], np.ndarray]:
        """Approach from above, reach down open, close while sinking as far as the closing hand allows (its
        fingers slide on the table), then lift. Returns the waypoints and the grasp position."""
        reach = self._jitter(np.array([*xy, self._grasp_height(height)]))
        grasp = np.array([*reach[:2], max(reach[2] - 0.03, self._grasp_height(height, 1.0))])
        up = np.array([0.0, 0.0, LIFT])
        return [
            Waypoint(np.array([*(reach + up), yaw]), self.open, self._steps(22)),
            Waypoint(np.array([*reach, yaw]), self.open, self._steps(16)),
            Waypoint(np.array([*grasp, yaw]), self.closed, self._steps(12)),
            Waypoint(np.array([*grasp, yaw]), self.closed, 4),
        ], grasp

    def _plan(self) -> list[Waypoint]:
        task, place = self.env.task, self.env.placement
        if isinstance(task, Lift):  # near the top of the upright can, from any side
            plan, grasp = self._grasp_plan(
                place.xy, 2 * task.half_height - 0.035, self.rng.uniform(-0.5, 0.5)
            )
            yaw = plan[0].pose[3]
            plan.append(Waypoint(np.array([*(grasp + [0, 0, 0.15]), yaw]), self.closed, self._steps(20)))
        elif isinstance(task, PickPlace):  # the banana lies along the tool's y axis, squeezed across
            yaw = self._axis_yaw(place.yaw + np.pi / 2 + self.rng.normal(0.0, 0.05))
            plan, grasp = self._grasp_plan(place.xy, task.radius, yaw)
            drop = self._jitter(np.array([*place.target_xy, grasp[2] + 0.03]))
            up = np.array([0.0, 0.0, LIFT])
            plan += [
                Waypoint(np.array([*(grasp + up), yaw]), self.closed, self._steps(18)),
                Waypoint(np.array([*(drop + up), yaw]), self.closed, self._steps(25)),
                Waypoint(np.array([*drop, yaw]), self.closed, self._steps(14)),
                Waypoint(np.array([*drop, yaw]), self.open, self._steps(10)),
                Waypoint(np.array([*(drop + up), yaw]), self.open, self._steps(14)),
            ]
        elif isinstance(task, PressButton):  # the grasp pose's foremost point onto the cap, pushed in
            yaw = self.rng.uniform(-0.5, 0.5)
            tip = self.tool.press_point
            depth = task.threshold + 0.004
            press = self._jitter(
                np.array([*(place.xy - tool_to_world(tip, yaw)[:2]), task.cap_top - depth + tip[2]])
            )
            plan = [
                Waypoint(np.array([*(press + [0, 0, 0.10]), yaw]), self.grasp, self._steps(22)),
                Waypoint(np.array([*press, yaw]), self.grasp, self._steps(16)),
            ]
        elif isinstance(task, PullDrawer):  # grasp the bar (along the tool's y axis), pull along -x
            handle = task.handle(self.env.scene, self.env.data)
            plan, grasp = self._grasp_plan(handle[:2], handle[2], self.rng.normal(0.0, 0.05))
            pulled = grasp - [task.opening + 0.05, 0, 0]
            plan.append(Waypoint(np.array([*pulled, plan[0].pose[3]]), self.closed, self._steps(25)))
        else:
            raise ValueError(f"no scripted expert for task '{task.name}'")
        return plan + [Waypoint(plan[-1].pose, plan[-1].hand, 40)]  # hold until the episode ends

    def act(self) -> np.ndarray:
        """The next action: waypoints interpolated with a smooth (minimum-jerk) profile, plus noise."""
        i = min(int(np.searchsorted(self.schedule, self.t, side="right")), len(self.plan) - 1)
        prev = self.plan[i - 1] if i > 0 else self.start
        s = min(1.0, (self.t - (self.schedule[i - 1] if i > 0 else 0) + 1) / self.plan[i].steps)
        s = s**3 * (10 - 15 * s + 6 * s**2)
        pose = prev.pose + s * (self.plan[i].pose - prev.pose)
        fingers = prev.hand + s * (self.plan[i].hand - prev.hand)
        self.t += 1
        wrist = np.array([*(pose[:3] + self.rng.normal(0.0, ACTION_NOISE, 3)), pose[3], 0.0, 0.0])
        return np.concatenate([wrist, fingers])

    @property
    def done(self) -> bool:
        return self.t >= self.schedule[-1]
