"""How a policy commands the simulator's wrist and hand.

`joints` (the default): action and state share one layout, the wrist's absolute pose and the hand's joints.
`ee_delta`: what a gripper on an arm with a Cartesian controller records. The action is a step of the
tool (`dx, dy, dz` in m, `dyaw` in rad) and a `grasp` command in 0 (open) .. 1 (closed). The state is the
wrist's joints and their velocities, and a `gripper` reading in -1 (open) .. 1 (closed). State and
action then hold different entries: the robot a joint map with `state_joints` / `action_joints` reads.

A hand on an arm (`ArmJoints`, an arm of `arms.spec` under `joints` control): action and state hold the
arm's joints, as its model names them, then the hand's.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from lerobot_opfa.arms.pose import ArmBody, FloatingWrist
from lerobot_opfa.envs.scene import WRIST_JOINTS, WRIST_RANGE
from lerobot_opfa.hands.model import HandModel

CONTROLS = ("joints", "ee_delta")
MAX_STEP = 0.05
"""m per step of `dx, dy, dz` (the experts move under 1 cm a step)."""
MAX_TURN = 0.3
"""rad per step of `dyaw`."""
EE_ACTION_NAMES = ("dx", "dy", "dz", "dyaw", "grasp")
EE_STATE_NAMES = (*WRIST_JOINTS, *(f"{joint}.vel" for joint in WRIST_JOINTS), "gripper")


def check_control(control: str, hand: str, dof: int) -> None:
    """`control` is one of `CONTROLS` and fits the hand: `ee_delta` drives a gripper."""
    if control not in CONTROLS:
        raise ValueError(f"unknown control '{control}'; valid controls: {', '.join(CONTROLS)}")
    if control == "ee_delta" and dof != 1:
        raise ValueError(
            f"control ee_delta drives a gripper (one actuated joint); hand '{hand}' has {dof}: use control "
            "'joints'"
        )


def gripper_closed(hand: HandModel) -> np.ndarray:
    """A gripper's closed pose: each joint at the limit its grasp pose lies towards (the grasp poses are
    set for larger objects than the benchmark's, so a gripper closes fully)."""
    open_, grasp = (hand.pose(name).double().cpu().numpy() for name in ("open", "grasp"))
    lower, upper = hand.lower.double().cpu().numpy(), hand.upper.double().cpu().numpy()
    return np.where(grasp > open_, upper, np.where(grasp < open_, lower, grasp))


class EndEffectorDeltas:
    """`ee_delta` control of a one-joint gripper on a wrist whose home is `home`: turns a step and a grasp
    command into the wrist's and the gripper's targets, keeping the wrist's target between steps, and
    reads the state it reports."""

    def __init__(self, hand: HandModel, home: np.ndarray) -> None:
        check_control("ee_delta", hand.name, hand.dof)
        self.open, self.closed = float(hand.pose("open")[0]), float(gripper_closed(hand)[0])
        self.action_space = gym.spaces.Box(
            np.array([-MAX_STEP] * 3 + [-MAX_TURN, 0.0], np.float32),
            np.array([MAX_STEP] * 3 + [MAX_TURN, 1.0], np.float32),
            dtype=np.float32,
        )
        self.home = home
        self.target = home.copy()

    def reset(self) -> None:
        self.target = self.home.copy()

    def targets(self, action: np.ndarray) -> np.ndarray:
        """The wrist pose and gripper joint targets of an `ee_delta` action (already within its space)."""
        self.target[:4] = np.clip(self.target[:4] + action[:4], WRIST_RANGE[:4, 0], WRIST_RANGE[:4, 1])
        return np.array([*self.target, self.open + action[4] * (self.closed - self.open)])

    def command(self, targets: np.ndarray) -> np.ndarray:
        """The `ee_delta` action that takes the wrist and gripper to `targets` (absolute, as the scripted
        experts give them; pitch and roll stay at home)."""
        grasp = (targets[len(WRIST_JOINTS)] - self.open) / (self.closed - self.open)
        return np.array([*(targets[:4] - self.target[:4]), np.clip(grasp, 0.0, 1.0)])

    def state(self, wrist: np.ndarray, wrist_velocity: np.ndarray, gripper: float) -> np.ndarray:
        reading = 2.0 * (gripper - self.open) / (self.closed - self.open) - 1.0
        return np.array([*wrist, *wrist_velocity, reading])


class ArmJoints:
    """A hand on a packaged arm (`arms.spec.load_arm`), kinematically: the action and the state are the
    arm's joints and the hand's. The wrist carriage follows the arm's FK (targets within the arm's joint
    limits, so the arm's reach is the hand's); the arm's links are not bodies of the scene (no collisions,
    not in the cameras), and the state's arm joints are the IK of the wrist the carriage holds, seeded at
    the last ones, as an encoder would read them."""

    def __init__(self, arm: str, hand: HandModel, home: np.ndarray) -> None:
        self.ref = arm
        """The arm as given (a built-in's name or a spec path): what the robot's joint map names."""
        self.body = ArmBody.load(arm, hand)
        self.floating = FloatingWrist()
        self.hand_dof = hand.dof
        arm_home = torch.tensor(self.body.home, dtype=torch.float64)
        self.home = self._ik(np.asarray(home, dtype=np.float64), arm_home)
        self.joints = self.home.copy()
        lower = np.maximum(self.body.lower.numpy(), -2 * np.pi)
        upper = np.minimum(self.body.upper.numpy(), 2 * np.pi)
        self.action_space = gym.spaces.Box(
            np.concatenate([lower, hand.lower.double().cpu().numpy()]).astype(np.float32),
            np.concatenate([upper, hand.upper.double().cpu().numpy()]).astype(np.float32),
            dtype=np.float32,
        )

    @property
    def names(self) -> tuple[str, ...]:
        """The arm's joints, as its model names them."""
        return self.body.joint_names

    def reset(self) -> None:
        self.joints = self.home.copy()

    def _ik(self, wrist_entries: np.ndarray, seed: torch.Tensor) -> np.ndarray:
        """The arm joints that put the hand's wrist where the carriage entries `wrist_entries` do."""
        pose = self.floating.pose(torch.from_numpy(wrist_entries)[None])
        q, _ = self.body.joints(pose, seed)
        return q[0].numpy()

    def targets(self, action: np.ndarray, wrist: np.ndarray) -> np.ndarray:
        """The carriage's and the hand's targets of an action (arm joints, hand joints; within its space),
        the carriage's Euler angles continuing those it holds (`wrist`)."""
        q = torch.from_numpy(action[: len(self.names)].astype(np.float64))[None]
        entries, _ = self.floating.joints(self.body.pose(q), torch.from_numpy(wrist))
        return np.concatenate([entries[0].numpy(), action[len(self.names) :]])

    def command(self, targets: np.ndarray) -> np.ndarray:
        """The action that takes the carriage and the hand to `targets` (the scripted experts' wrist pose and
        hand joints): the arm's joints by IK, seeded at those it holds."""
        arm = self._ik(targets[: len(WRIST_JOINTS)], torch.from_numpy(self.joints))
        return np.concatenate([arm, targets[len(WRIST_JOINTS) :]])

    def state(self, wrist: np.ndarray, hand: np.ndarray) -> np.ndarray:
        """The arm's joints for the wrist the carriage holds (seeded at the last), then the hand's."""
        self.joints = self._ik(np.asarray(wrist, dtype=np.float64), torch.from_numpy(self.joints))
        return np.concatenate([self.joints, hand])
