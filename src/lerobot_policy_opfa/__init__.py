"""LeRobot discovers plugins by distribution name (`lerobot_policy_*`); importing this registers OPFA."""

import lerobot_opfa  # noqa: F401
