"""LeRobot discovers plugins by distribution name (`lerobot_policy_*`); importing this registers OPFA: the
`opfa` env type and gymnasium ids, the `opfa` policy with its processor steps, and the simulated rig
(`opfa_sim` robot, `opfa_expert` teleoperator), and has LeRobot's batch converter keep a robot's
`robot_type` (`lerobot_opfa.policy.robot_type`). In LeRobot's command lines, and only there, it also
shortens this package's refusals to one line (`lerobot_opfa.command_errors`) and picks MuJoCo's headless
OpenGL backend where there is no display (`lerobot_opfa.envs.choose_headless_gl`)."""

from lerobot_opfa.command_errors import running_lerobot_command, shorten_refusals_in_lerobot_commands
from lerobot_opfa.envs import choose_headless_gl

if running_lerobot_command():
    choose_headless_gl()  # before the imports below load MuJoCo
shorten_refusals_in_lerobot_commands()

from lerobot_opfa import rig as _rig  # noqa: E402, F401
from lerobot_opfa.envs import config as _env_config  # noqa: E402, F401
from lerobot_opfa.policy import configuration_opfa as _policy_config  # noqa: E402, F401
from lerobot_opfa.policy import depth_step as _depth_step  # noqa: E402, F401
from lerobot_opfa.policy import joint_steps as _joint_steps  # noqa: E402, F401
from lerobot_opfa.policy import normalization as _normalization  # noqa: E402, F401
from lerobot_opfa.policy.robot_type import register_robot_type  # noqa: E402

register_robot_type()
