"""Scripted experts: wrist waypoints in the hand's tool frame plus closures between the spec's open and
grasp poses.

Because the wrist is driven in the tool frame (see `toolframe`), the same waypoints serve every hand;
per hand its geometry enters: how far it reaches past its grasp centre as it closes (the wrist never
drives it into the table) and the direction along which its thumb closes on the fingers (an elongated
object lies across it). Every episode draws its own waypoint offsets, yaw, timing and per-step action
noise, so demonstrations vary."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_opfa.envs.control import gripper_closed
from lerobot_opfa.envs.env import ArmView, OpfaSimEnv
from lerobot_opfa.envs.scene import tool_to_world
from lerobot_opfa.envs.tasks import Lift, LiftBox, PickPlace, PressButton, PullDrawer

# Hands close this far past the spec's grasp pose (clipped to the limits), so the servos keep squeezing an
# object that stops the fingers short of the pose; grippers close to their limit (their grasp poses are
# set for larger objects than these tasks'). Squeezing harder (1.4) pops small objects out of some hands.
SQUEEZE = 1.3
CLOSE_STEPS = 18  # closing takes about 0.9 s: fingers that strike the object push it away before it is held
RELEASE = 0.5  # closure the hand relaxes to before it withdraws: opening wide at once flings the object
POSITION_NOISE = 0.004  # m, per waypoint
ACTION_NOISE = 0.001  # m, per step on the wrist position
CLEARANCE = 0.004  # m, between the hand and the table
LIFT = 0.12  # m, approach from and retreat to this far above a grasp
SINK = 0.03  # m, the hand sinks this much while closing (as far as the closing hand clears the table)
GRASP_DEPTH = 0.035  # m, the grasp centre reaches this far below the top of the object to lift
DROP = 0.01  # m, a carried object is let go this far above where it comes to rest

# m, along the tool's +y (the side the fingers curl from): a can placed where thumb and fingertips meet it
# (`ToolFrame.grasp_centre`) is still swept 2-4 cm towards -y by the curling fingers, and the can knocked
# over lay that side of it. Measured over 20 lift episodes (mujoco 4.0.1 and 4.0.0), with 0.015 every hand
# tried lifted it 18-20 times (the grasp centre alone: 17-20, the tool origin: 6-20).
CURL_MARGIN = 0.015

# Per hand, m: grasp the banana this far along its axis from the middle (towards where the fingertips
# gather). Measured: the Shadow hand, grasping the middle, holds the banana by one end, tilted, and it
# topples off the plate when let go (90% success over 50 episodes; 100% with this offset).
ALONG_BANANA = {"shadow": 0.015}

# (task, hand) pairs left out of the benchmark's targets, with the reason (measured by bench_sim.py).
EXCLUDED_PAIRS: dict[tuple[str, str], str] = {}


@dataclass
class Waypoint:
    """Reach the tool pose `pose` (x, y, z, yaw) and the hand closure `closure` over `steps` steps."""

    pose: np.ndarray
    closure: float  # 0 the spec's open pose, 1 its grasp pose, SQUEEZE closed
    steps: int
    carry: bool = False  # `pose` is where the held object goes: the tool keeps its offset from the object


class ScriptedExpert:
    """Plans one episode from the state after `env.reset` and returns an action per step: one arm's
    expert per arm, their waypoints timed alike so that two hands close, and lift, together."""

    def __init__(self, env: OpfaSimEnv, rng: np.random.Generator) -> None:
        self.env = env
        self.arms = [ArmExpert(env.arm(side), rng) for side in env.hand_models]
        steps = np.max([[w.steps for w in arm.plan] for arm in self.arms], axis=0)
        for arm in self.arms:
            for waypoint, n in zip(arm.plan, steps, strict=True):
                waypoint.steps = int(n)
            arm.schedule = np.cumsum(steps)

    def act(self) -> np.ndarray:
        return np.concatenate([arm.act() for arm in self.arms])

    @property
    def done(self) -> bool:
        return all(arm.done for arm in self.arms)


class ArmExpert:
    """One arm's expert: plans its part of the episode and gives its wrist's and hand's targets."""

    def __init__(self, env: ArmView, rng: np.random.Generator) -> None:
        self.env, self.rng = env, rng
        hand = env.hand_model
        self.open = env.hand_open
        self.grasp = hand.pose("grasp").double().cpu().numpy()
        self.lower, self.upper = hand.lower.double().cpu().numpy(), hand.upper.double().cpu().numpy()
        if hand.spec.kind == "gripper":
            self.closed = gripper_closed(hand)
        else:
            self.closed = np.clip(self.open + SQUEEZE * (self.grasp - self.open), self.lower, self.upper)
        self.tool = env.arm.tool
        self.start = Waypoint(np.array([*env.home[:3], env.home[3]]), 0.0, 1)
        self.plan = self._plan()
        self.schedule = np.cumsum([w.steps for w in self.plan])
        self.t = 0
        self.held: np.ndarray | None = None  # tool minus object position, measured when carrying starts

    def hand_pose(self, closure: float) -> np.ndarray:
        """Joint targets: linear from the open (0) to the grasp pose (1), then on to the closed pose."""
        if closure <= 1.0:
            q = self.open + closure * (self.grasp - self.open)
        else:
            q = self.grasp + (closure - 1.0) / (SQUEEZE - 1.0) * (self.closed - self.grasp)
        return np.clip(q, self.lower, self.upper)

    def _jitter(self, xyz: np.ndarray) -> np.ndarray:
        return xyz + self.rng.normal(0.0, POSITION_NOISE, 3)

    def _steps(self, n: int) -> int:
        return max(2, int(round(n * self.rng.uniform(0.85, 1.15))))

    def _grasp_plan(self, xy: np.ndarray, height: float, yaw: float) -> tuple[list[Waypoint], np.ndarray]:
        """Approach from above, reach down open (no lower than the open hand clears the table), close
        slowly while sinking (as far as the closing hand clears the table, see `act`). Returns the
        waypoints and the grasp position."""
        reach = self._jitter(np.array([*xy, height]))
        reach[2] = max(reach[2], self.tool.reach_at(0.0) + CLEARANCE)
        grasp = reach - [0.0, 0.0, SINK]
        up = np.array([0.0, 0.0, LIFT])
        return [
            Waypoint(np.array([*(reach + up), yaw]), 0.0, self._steps(22)),
            Waypoint(np.array([*reach, yaw]), 0.0, self._steps(16)),
            Waypoint(np.array([*grasp, yaw]), SQUEEZE, self._steps(CLOSE_STEPS)),
            Waypoint(np.array([*grasp, yaw]), SQUEEZE, 4),
        ], grasp

    def _plan(self) -> list[Waypoint]:
        task, place = self.env.task, self.env.placement
        if isinstance(task, Lift):  # near the top of the upright object, from any side (a box's face)
            yaw = (
                place.yaw + self.rng.normal(0.0, 0.05)
                if isinstance(task, LiftBox)
                else self.rng.uniform(-0.5, 0.5)
            )
            # A hand's thumb and fingers close on the can from different sides along arcs: the can goes
            # where they meet it together, CURL_MARGIN out along +y. Grippers close on their centre; boxes
            # and bananas did worse so placed (shadow: 9 and 11 of 20 against 19 and 20).
            xy = place.xy
            if self.env.hand_model.spec.kind == "hand" and not isinstance(task, LiftBox):
                centre = self.tool.grasp_centre(2 * task.radius) * [1, 1, 0] + [0, CURL_MARGIN, 0]
                xy = xy - tool_to_world(centre, yaw)[:2]
            plan, grasp = self._grasp_plan(xy, 2 * task.half_height - GRASP_DEPTH, yaw)
            plan.append(Waypoint(np.array([*(grasp + [0, 0, 0.15]), yaw]), SQUEEZE, self._steps(20)))
        elif isinstance(task, PickPlace):
            # The banana lies across the thumb's squeeze direction, its inner curve (local +y) towards the
            # thumb, so its ends bend round the thumb instead of into the fingers. Seen from above the
            # tool frame is mirrored (`tool_to_world`): the squeeze points along world yaw - squeeze_angle.
            squeeze = self.tool.squeeze_angle
            yaw = place.yaw + np.pi / 2 + squeeze + self.rng.normal(0.0, 0.05)
            yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
            along = ALONG_BANANA.get(self.env.hand_model.name, 0.0) * np.array(
                [-np.sin(squeeze), np.cos(squeeze), 0]
            )
            plan, grasp = self._grasp_plan(place.xy - tool_to_world(along, yaw)[:2], task.radius, yaw)
            drop = self._jitter(np.array([*place.target_xy, 2 * task.plate_half + task.radius + DROP]))
            up = np.array([0.0, 0.0, LIFT])
            plan += [
                Waypoint(np.array([*(grasp + up), yaw]), SQUEEZE, self._steps(18)),
                Waypoint(np.array([*(drop + up), yaw]), SQUEEZE, self._steps(25), carry=True),
                Waypoint(np.array([*drop, yaw]), SQUEEZE, self._steps(14), carry=True),
                Waypoint(np.array([*drop, yaw]), RELEASE, self._steps(10), carry=True),
                Waypoint(np.array([*(drop + up), yaw]), 0.0, self._steps(14), carry=True),
            ]
        elif isinstance(task, PressButton):  # the grasp pose's foremost point onto the cap, pushed in
            yaw = self.rng.uniform(-0.5, 0.5)
            tip = self.tool.press_point
            depth = task.threshold + 0.004
            press = self._jitter(
                np.array([*(place.xy - tool_to_world(tip, yaw)[:2]), task.cap_top - depth + tip[2]])
            )
            plan = [
                Waypoint(np.array([*(press + [0, 0, 0.10]), yaw]), 1.0, self._steps(22)),
                Waypoint(np.array([*press, yaw]), 1.0, self._steps(16)),
            ]
        elif isinstance(task, PullDrawer):  # grasp the bar (along the tool's y axis), pull along -x
            handle = task.handle(self.env.scene, self.env.data)
            yaw = self.rng.normal(0.0, 0.05)
            plan, grasp = self._grasp_plan(handle[:2], handle[2], yaw)
            pulled = grasp - [task.opening + 0.05, 0, 0]
            plan.append(Waypoint(np.array([*pulled, yaw]), SQUEEZE, self._steps(25)))
        else:
            raise ValueError(f"no scripted expert for task '{task.name}'")
        return plan + [Waypoint(plan[-1].pose, plan[-1].closure, 40)]  # hold until the episode ends

    def _target(self, waypoint: Waypoint) -> np.ndarray:
        """The waypoint's tool pose; for a carry waypoint, shifted by where the object sits in the hand
        (grasps move objects off the grasp centre), so the object, not the hand, gets there."""
        if not waypoint.carry:
            return waypoint.pose
        if self.held is None:
            obj = self.env.task.env_state(self.env.scene, self.env.data)[:3]
            self.held = self.env.data.qpos[self.env.arm.wrist_qpos[:3]] - obj
        return waypoint.pose + [*self.held, 0.0]

    def act(self) -> np.ndarray:
        """The next action: waypoints interpolated with a smooth (minimum-jerk) profile, the wrist kept
        high enough that the hand, at its current closure, clears the table, plus noise."""
        i = min(int(np.searchsorted(self.schedule, self.t, side="right")), len(self.plan) - 1)
        prev = self.plan[i - 1] if i > 0 else self.start
        s = min(1.0, (self.t - (self.schedule[i - 1] if i > 0 else 0) + 1) / self.plan[i].steps)
        s = s**3 * (10 - 15 * s + 6 * s**2)
        pose = self._target(prev) + s * (self._target(self.plan[i]) - self._target(prev))
        closure = prev.closure + s * (self.plan[i].closure - prev.closure)
        pose[2] = max(pose[2], self.tool.reach_at(closure) + CLEARANCE)
        self.t += 1
        wrist = np.array([*(pose[:3] + self.rng.normal(0.0, ACTION_NOISE, 3)), pose[3], 0.0, 0.0])
        return np.concatenate([wrist, self.hand_pose(closure)])

    @property
    def done(self) -> bool:
        return self.t >= self.schedule[-1]
