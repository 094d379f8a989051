"""lerobot-opfa: one policy for grippers and dexterous hands of any joint count, trained in GaLR space."""

__version__ = "0.1.0"
