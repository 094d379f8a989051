"""Hand models: specs, batched FK, reachable-state sampling and surface point clouds.

The names below load on first use, so `lerobot-opfa hands list` and spec checks do not pay for torch."""

from importlib import import_module

_EXPORTS = {
    "HandCloud": "model",
    "HandModel": "model",
    "builtin_hands": "registry",
    "load_hand": "registry",
    "load_spec": "registry",
    "HandSpec": "spec",
    "HandSpecError": "spec",
    "FINGERS": "universal",
    "UNIVERSAL_JOINTS": "universal",
    "UNIVERSAL_JOINT_NAMES": "universal",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'lerobot_opfa.hands' has no attribute '{name}'")
    return getattr(import_module(f"lerobot_opfa.hands.{_EXPORTS[name]}"), name)
