"""The `opfa` LeRobot policy: configuration, model, processors (modules named as LeRobot expects).
Importing any of it registers the processor steps a checkpoint's pipelines name, which LeRobot's registry
finds by name: a policy loaded in Python loads its processors as it would through the plugin."""

from lerobot_opfa.policy import depth_step, joint_steps, normalization  # noqa: F401
