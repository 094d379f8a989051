"""MuJoCo cross-embodiment benchmark: scenes, tasks, scripted experts, the `opfa` LeRobot env.

Importing this package registers nothing by itself beyond what `config` does."""

import os
import sys

DEFAULT_FPS = 20
"""The simulator's control rate unless a robot says its own (steps of the policy or expert per second)."""


def choose_headless_gl() -> None:
    """Picks EGL as MuJoCo's OpenGL backend when none is chosen and there is no display: MuJoCo reads
    `MUJOCO_GL` once, at its own import, and its default (GLFW) cannot render on a headless machine. It is
    a choice for the whole process, so only command lines make it (`cli.main`, and the plugin in
    LeRobot's), before MuJoCo is imported."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        os.environ.setdefault("MUJOCO_GL", "egl")
