"""`--teleop.type=opfa_expert`: the benchmark's scripted expert as a LeRobot `Teleoperator`, so that
`lerobot-record --robot.type=opfa_sim --teleop.type=opfa_expert` records demos with LeRobot's own recorder.
It drives the connected `opfa_sim` rig of the same id: it plans each episode from the scene the rig has
just placed, as `sim demos` does."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from lerobot.teleoperators.config import TeleoperatorConfig
from lerobot.teleoperators.teleoperator import Teleoperator

from lerobot_opfa.envs.experts import ScriptedExpert
from lerobot_opfa.rig.robot import LIVE_RIGS, POSITION


@TeleoperatorConfig.register_subclass("opfa_expert")
@dataclass(kw_only=True)
class OpfaExpertConfig(TeleoperatorConfig):
    robot_id: str = "opfa_sim"  # the `--robot.id` of the rig it drives


class OpfaExpert(Teleoperator):
    config_class = OpfaExpertConfig
    name = "opfa_expert"

    def __init__(self, config: OpfaExpertConfig):
        super().__init__(config)
        self.config = config
        self._connected = False
        self._expert: ScriptedExpert | None = None
        self._episode: int | None = None

    @property
    def rig(self):
        rig = LIVE_RIGS.get(self.config.robot_id)
        if rig is None:
            raise RuntimeError(
                f"opfa_expert drives a connected opfa_sim rig with id '{self.config.robot_id}', and there is "
                f"none (connected: {list(LIVE_RIGS) or 'none'}); use --robot.type=opfa_sim"
            )
        return rig

    @property
    def action_features(self) -> dict:
        return self.rig.action_features

    @property
    def feedback_features(self) -> dict:
        return {}

    @property
    def is_connected(self) -> bool:
        return self._connected

    @property
    def is_calibrated(self) -> bool:
        return True

    def connect(self, calibrate: bool = True) -> None:
        """LeRobot connects the teleoperator before the robot: the rig is looked up at the first action."""
        self._connected = True

    def calibrate(self) -> None:
        """Nothing to calibrate."""

    def configure(self) -> None:
        """Nothing to configure."""

    def get_action(self) -> dict[str, Any]:
        rig = self.rig
        if rig.episode != self._episode:  # the rig placed a new scene: plan it
            self._expert = ScriptedExpert(rig.env, np.random.default_rng(rig.config.seed + rig.episode))
            self._episode = rig.episode
        action = rig.env.command(self._expert.act())  # on an arm: its joints, by IK
        return {f"{n}{POSITION}": float(v) for n, v in zip(rig.joint_names, action, strict=True)}

    def send_feedback(self, feedback: dict[str, Any]) -> None:
        """The expert reads the scene itself."""

    def disconnect(self) -> None:
        self._connected = False
