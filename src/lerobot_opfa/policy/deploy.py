"""`lerobot-opfa policy for-robot`: a copy of a checkpoint of several robots that drives one of them, or
of a checkpoint that drives a robot whose `robot_type` names other hands, by the user's word.

A frame says which robot it comes from (`joint_steps`); a robot's frames in `lerobot-rollout` say it by
their `robot_type` (`robot_type.py`), where it names the robot's hands. Where it does not (a robot named
`so101_follower`), the checkpoint itself names the robot: its encode step's `hand`, saved with it. Nothing
is guessed from a state's width, which two hands can share.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from lerobot.configs import PreTrainedConfig
from lerobot.policies.factory import make_pre_post_processors
from lerobot.processor import PolicyProcessorPipeline
from lerobot.utils.import_utils import register_third_party_plugins

from lerobot_opfa.datasets.io import atomic_directory
from lerobot_opfa.policy.joint_steps import OpfaEncodeJointsStep


def checkpoint_config(policy_dir: Path) -> PreTrainedConfig:
    """The config of a checkpoint folder (its `pretrained_model`), or a one-line error. Its policy type and
    processor steps are registered as LeRobot's own scripts register them, from the installed plugins
    (a fresh `lerobot-opfa policy` process has imported none)."""
    if not (policy_dir / "config.json").is_file():
        raise ValueError(f"{policy_dir}: not a checkpoint folder (no config.json; give its pretrained_model)")
    register_third_party_plugins()
    return PreTrainedConfig.from_pretrained(policy_dir)


def write_copy(policy_dir: Path, output: Path | str, *pipelines: PolicyProcessorPipeline) -> Path:
    """`policy_dir` copied to `output` (atomically) with `pipelines` saved over its own."""
    with atomic_directory(output) as partial:
        shutil.copytree(policy_dir, partial)
        for pipeline in pipelines:
            pipeline.save_pretrained(partial)
    return Path(output)


def pin_robot(policy_dir: Path | str, hand: str, output: Path | str, robot_type: str | None = None) -> Path:
    """Copies the checkpoint folder `policy_dir` to `output` with its frames read as `hand`'s robot, also
    where the robot's `robot_type` names other hands than `hand`'s."""
    policy_dir = Path(policy_dir)
    pre, _ = make_pre_post_processors(checkpoint_config(policy_dir), pretrained_path=str(policy_dir))
    encode = next((s for s in pre.steps if isinstance(s, OpfaEncodeJointsStep)), None)
    if encode is None:
        raise ValueError(
            f"{policy_dir} does not map joints (a stock policy before `policy convert-io`): nothing to pin"
        )
    encode.pinned_robot(hand)  # one of its robots, or a one-line error naming them
    encode.hand, encode.accept_robot_type = hand, robot_type
    return write_copy(policy_dir, output, pre)
