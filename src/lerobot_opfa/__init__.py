"""lerobot-opfa: one policy for grippers and dexterous hands of any joint count, trained in GaLR space."""

from lerobot_opfa.envs import config as _env_config  # noqa: F401  (registers the `opfa` env type)

__version__ = "0.1.0"
