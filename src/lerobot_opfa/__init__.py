"""lerobot-opfa: one policy for grippers and dexterous hands of any joint count, trained in GaLR space.

Importing the package loads nothing heavy; LeRobot's plugin discovery imports `lerobot_policy_opfa`, which
registers the `opfa` policy and env types."""

__version__ = "0.1.0"
