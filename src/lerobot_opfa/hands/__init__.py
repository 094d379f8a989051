"""Hand models: specs, batched FK, reachable-state sampling and surface point clouds."""

from lerobot_opfa.hands.model import HandCloud, HandModel
from lerobot_opfa.hands.registry import builtin_hands, load_hand, load_spec
from lerobot_opfa.hands.spec import HandSpec, HandSpecError
from lerobot_opfa.hands.universal import FINGERS, UNIVERSAL_JOINT_NAMES, UNIVERSAL_JOINTS

__all__ = [
    "FINGERS",
    "UNIVERSAL_JOINTS",
    "UNIVERSAL_JOINT_NAMES",
    "HandCloud",
    "HandModel",
    "HandSpec",
    "HandSpecError",
    "builtin_hands",
    "load_hand",
    "load_spec",
]
