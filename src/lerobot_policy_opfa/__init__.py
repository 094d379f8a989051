"""LeRobot discovers plugins by distribution name (`lerobot_policy_*`); importing this registers OPFA: the
`opfa` env type and gymnasium ids, the `opfa` policy with its processor steps, and the simulated rig
(`opfa_sim` robot, `opfa_expert` teleoperator); in LeRobot's command lines it also shortens this package's
refusals to one line (`lerobot_opfa.command_errors`)."""

from lerobot_opfa import rig as _rig  # noqa: F401
from lerobot_opfa.command_errors import shorten_refusals_in_lerobot_commands
from lerobot_opfa.envs import config as _env_config  # noqa: F401
from lerobot_opfa.policy import configuration_opfa as _policy_config  # noqa: F401
from lerobot_opfa.policy import depth_step as _depth_step  # noqa: F401
from lerobot_opfa.policy import joint_steps as _joint_steps  # noqa: F401
from lerobot_opfa.policy import normalization as _normalization  # noqa: F401

shorten_refusals_in_lerobot_commands()
