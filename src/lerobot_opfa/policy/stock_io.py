"""`lerobot-opfa policy convert-io`: give a stock LeRobot policy trained in GaLR space (on a
`dataset latent` dataset) a joint-space interface, so `lerobot-eval` can run it on any hand the GaLR knows.

The policy's own processors stay as they are; `opfa_encode_joints` goes in front of its normaliser
(hand joints -> wrist + z) and `opfa_decode_joints` after its unnormaliser (wrist + z -> that hand's
joints). The GaLR's weights are saved with those steps, so the converted checkpoint is self-contained.
"""

from __future__ import annotations

import dataclasses
import shutil
import uuid
from pathlib import Path

from lerobot.configs import PreTrainedConfig
from lerobot.policies.factory import make_pre_post_processors

from lerobot_opfa.galr.frozen import galr_hand_refs, load_galr
from lerobot_opfa.policy.joint_steps import OpfaDecodeJointsStep, OpfaEncodeJointsStep


def convert_policy_io(
    policy_dir: Path | str, galr_path: str, output: Path | str, hand: str | None = None
) -> Path:
    """Copies the checkpoint folder `policy_dir` to `output` with joint-space processors."""
    policy_dir, output = Path(policy_dir), Path(output)
    if not (policy_dir / "config.json").is_file():
        raise ValueError(f"{policy_dir}: not a checkpoint folder (no config.json; give its pretrained_model)")
    config = PreTrainedConfig.from_pretrained(policy_dir)
    if config.type == "opfa":
        raise ValueError(f"{policy_dir} is an opfa policy: its processors already take and give joints")
    pre, post = make_pre_post_processors(config, pretrained_path=str(policy_dir))
    galr = load_galr(str(galr_path))
    hands = galr.config.hand_names
    width = config.output_features["action"].shape[0]
    if width <= galr.config.latent_dim:
        raise ValueError(
            f"the policy's action has {width} entries, fewer than wrist + z ({galr.config.latent_dim})"
        )
    shared = dict(
        action_space="galr", embodiments=hands, hand_refs=galr_hand_refs(galr),
        wrist_dim=width - galr.config.latent_dim, galr_config=dataclasses.asdict(galr.config),
        link=uuid.uuid4().hex, galr=galr,
    )  # fmt: skip
    pre_names = [type(s).__name__ for s in pre.steps]
    post_names = [type(s).__name__ for s in post.steps]
    if "NormalizerProcessorStep" not in pre_names or "UnnormalizerProcessorStep" not in post_names:
        raise ValueError(f"expected LeRobot's (un)normaliser steps, got {pre_names} and {post_names}")
    pre.steps.insert(pre_names.index("NormalizerProcessorStep"), OpfaEncodeJointsStep(**shared, hand=hand))
    post.steps.insert(post_names.index("UnnormalizerProcessorStep") + 1, OpfaDecodeJointsStep(**shared))
    if output.exists():
        raise FileExistsError(f"{output} exists")
    shutil.copytree(policy_dir, output)
    pre.save_pretrained(output)
    post.save_pretrained(output)
    return output
