"""The benchmark as LeRobot hardware: the `opfa_sim` robot and the `opfa_expert` teleoperator (LeRobot
finds each device class beside its registered config, in this package)."""

from lerobot_opfa.rig.robot import OpfaSimRobot, OpfaSimRobotConfig
from lerobot_opfa.rig.teleop import OpfaExpert, OpfaExpertConfig

__all__ = ["OpfaExpert", "OpfaExpertConfig", "OpfaSimRobot", "OpfaSimRobotConfig"]
