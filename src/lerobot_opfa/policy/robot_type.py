"""A deployed robot's `robot_type`, carried to the preprocessor, where the checkpoint's robots meet it.

LeRobot 0.6.1 puts the robot's `robot_type` into every observation batch it runs a policy on
(`prepare_observation_for_inference`, in `lerobot-rollout` and in `lerobot-record` with a policy), and its
converter `batch_to_transition` then keeps, besides the padding flags, only the complementary keys that
`lerobot.processor.converters._COMPLEMENTARY_KEYS` names: `robot_type` is dropped. The converter reads that
tuple at call time, so naming `robot_type` in it once, when the plugin loads, brings the robot's type to
`opfa_encode_joints` as complementary data. No seam carries it otherwise (`lerobot-rollout` takes no
processor overrides); `tests/test_robot_type.py` fails when LeRobot's converters change.
"""

from __future__ import annotations

from lerobot_opfa.features import ROBOT_TYPE


def register_robot_type() -> None:
    """Has LeRobot's batch converter keep a batch's `robot_type` (idempotent)."""
    from lerobot.processor import converters

    if ROBOT_TYPE not in converters._COMPLEMENTARY_KEYS:
        converters._COMPLEMENTARY_KEYS = (*converters._COMPLEMENTARY_KEYS, ROBOT_TYPE)
