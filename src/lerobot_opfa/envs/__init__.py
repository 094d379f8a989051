"""MuJoCo cross-embodiment benchmark: scenes, tasks, scripted experts, the `opfa` LeRobot env.

Importing this package registers nothing by itself beyond what `config` does; it only picks EGL as
MuJoCo's OpenGL backend when none is chosen and there is no display, because MuJoCo reads `MUJOCO_GL`
once at import and its default (GLFW) cannot render on a headless machine."""

import os
import sys

if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
    os.environ.setdefault("MUJOCO_GL", "egl")
