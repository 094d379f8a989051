"""lerobot-opfa: one policy for grippers and dexterous hands of any joint count, trained in GaLR space."""

from lerobot_opfa.envs import config as _env_config  # noqa: F401  (registers the `opfa` env type)
from lerobot_opfa.policy import normalization as _policy  # noqa: F401  (registers the `opfa` policy + steps)

__version__ = "0.1.0"
