"""Any LeRobot policy in GaLR space: the paper's OPFA is base-policy-agnostic (ACT, diffusion, ...), the
only change being that the policy predicts body + z instead of joints.

LeRobot 0.6.1's `lerobot-train` builds a stock policy's processors with its own factory and offers no seam
for a transform, so the transform runs once over the dataset. `latent_dataset` writes a copy of a
dataset `opfa` trains on (native or merged) whose `observation.state` and `action` are the normalised
policy space: the steps `opfa`'s preprocessor runs (the joint maps, the GaLR encode, the per-embodiment
normalisation fitted the same way), applied to every frame. Cameras and the other features are kept, so
a stock policy trains with its own image encoder. The steps are saved beside the frames
(`meta/opfa_steps`). `convert_checkpoint` splices them around a trained stock checkpoint's own steps:
robot entries -> policy space before its normaliser, and after its unnormaliser the clamp to the
training range and the decode to the robot's entries. Its normaliser sees data already about [-1, 1] and
normalises it again, the same at training and at inference.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import torch
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.dataset_tools import modify_features, recompute_stats
from lerobot.datasets.io_utils import write_info
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors
from lerobot.processor import PolicyProcessorPipeline, TransitionKey, create_transition
from lerobot.processor.converters import (
    batch_to_transition,
    policy_action_to_transition,
    transition_to_batch,
    transition_to_policy_action,
)
from lerobot.processor.relative_action_processor import RelativeActionsProcessorStep
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa.datasets.io import (
    OPFA_META_FILE,
    atomic_directory,
    check_dataset_folder,
    check_outside_inputs,
    read_columns,
    read_json,
)
from lerobot_opfa.datasets.layout import LATENT_ROBOT_TYPE
from lerobot_opfa.datasets.merge import BOOKKEEPING
from lerobot_opfa.features import OBS_EMBODIMENT
from lerobot_opfa.policy.configuration_opfa import OpfaConfig
from lerobot_opfa.policy.deploy import checkpoint_config, write_copy
from lerobot_opfa.policy.joint_steps import OpfaEncodeJointsStep
from lerobot_opfa.policy.processor_opfa import PolicySpaceSteps, hand_entry_names, policy_space_steps
from lerobot_opfa.policy.record import resolve_config

STEPS_DIR = Path("meta") / "opfa_steps"
"""Where a latent dataset keeps the steps its frames went through."""
TO_POLICY, TO_ROBOT = "to_policy_space.json", "to_robot.json"
CHUNK = 4096
"""Frames converted at once."""


def latent_dataset(
    source: Path | str, output: Path | str, galr_path: str | None = None, drop: tuple[str, ...] = (),
    overwrite: bool = False, joint_map: Path | str | None = None,
) -> Path:  # fmt: skip
    """Writes `output` (atomically): `source`'s frames with state and action in the normalised policy
    space, without the features `drop` names (a robot's dataset read through `joint_map`); returns it."""
    (source,) = check_outside_inputs([source], output)
    check_dataset_folder(source)
    meta = LeRobotDatasetMetadata(f"local/{source.name}", root=source)
    kept = (OBS_STATE, ACTION, OBS_EMBODIMENT, *BOOKKEEPING)
    refused = [k for k in drop if k not in meta.features or k in kept]
    if refused:
        raise ValueError(
            f"--drop {', '.join(refused)}: not a feature of {source} that may go (its features: "
            f"{', '.join(k for k in meta.features if k not in kept)})"
        )
    config = OpfaConfig(device="cpu", galr_path=galr_path, joint_map=joint_map and str(joint_map))
    config, layout, galr = resolve_config(config, meta)
    steps = policy_space_steps(config, meta, layout, galr)
    state, action = _policy_space_frames(steps, source, layout.kind == "merged")
    hand = hand_entry_names(config, layout, steps.encode)
    infos = {
        key: {"dtype": "float32", "shape": (len(body) + len(hand),), "names": [*body, *hand]}
        for key, body in ((OBS_STATE, config.wrist_names), (ACTION, config.action_body))
    }
    output = Path(output)
    with (
        atomic_directory(output, overwrite) as partial,
        tempfile.TemporaryDirectory(dir=partial.parent, prefix=f".{output.name}.stage") as stage,
    ):
        dataset = LeRobotDataset(meta.repo_id, root=source)
        without = modify_features(
            dataset, remove_features=[OBS_STATE, ACTION, *drop], output_dir=Path(stage) / "frames",
            repo_id=f"local/{output.name}",
        )  # fmt: skip
        written = modify_features(
            without, add_features={OBS_STATE: (state, infos[OBS_STATE]), ACTION: (action, infos[ACTION])},
            output_dir=partial, repo_id=f"local/{output.name}",
        )  # fmt: skip
        recompute_stats(written)
        written.meta.info.robot_type = LATENT_ROBOT_TYPE  # not joints: `dataset merge` refuses it
        write_info(written.meta.info, partial)
        save_steps(steps, partial / STEPS_DIR)
        record = {"policy_space": True, "source": str(source), "embodiments": config.embodiments}
        (partial / OPFA_META_FILE).write_text(json.dumps(record, indent=2))
    return output


def _policy_space_frames(steps: PolicySpaceSteps, root: Path, merged: bool) -> tuple[np.ndarray, np.ndarray]:
    """Every frame's state and action through the encode and normalise steps, in file order."""
    columns = read_columns(root, [OBS_STATE, ACTION] + ([OBS_EMBODIMENT] if merged else []))
    out = {OBS_STATE: [], ACTION: []}
    for start in range(0, len(columns[OBS_STATE]), CHUNK):
        rows = {k: torch.tensor(v[start : start + CHUNK]) for k, v in columns.items()}
        observation = {k: v for k, v in rows.items() if k != ACTION}
        transition = steps.normalize(
            steps.encode(create_transition(observation=observation, action=rows[ACTION]))
        )
        out[OBS_STATE].append(transition[TransitionKey.OBSERVATION][OBS_STATE].numpy())
        out[ACTION].append(transition[TransitionKey.ACTION].numpy())
    return tuple(np.concatenate(out[k]).astype(np.float32) for k in (OBS_STATE, ACTION))


def save_steps(steps: PolicySpaceSteps, folder: Path) -> None:
    PolicyProcessorPipeline(steps=[steps.encode, steps.normalize], name="to_policy_space").save_pretrained(
        folder, config_filename=TO_POLICY
    )
    PolicyProcessorPipeline(steps=[steps.unnormalize, steps.decode], name="to_robot").save_pretrained(
        folder, config_filename=TO_ROBOT
    )


def load_steps(folder: Path, hand: str | None = None) -> PolicySpaceSteps:
    """The steps a latent dataset saved, the postprocessor's paired with the encode step; `hand`:
    the robot of frames that do not say (`OpfaEncodeJointsStep.hand`)."""
    if not (folder / TO_POLICY).is_file():
        raise ValueError(
            f"{folder.parent.parent} is not a latent dataset (no {STEPS_DIR}); the stock policy must be "
            "trained on one: `lerobot-opfa policy latent-dataset --input DATASET --output OUT`"
        )
    overrides = {"opfa_encode_joints": {"hand": hand}} if hand else {}
    to_policy = PolicyProcessorPipeline.from_pretrained(
        folder, config_filename=TO_POLICY, overrides=overrides, to_transition=batch_to_transition,
        to_output=transition_to_batch,
    )  # fmt: skip
    to_robot = PolicyProcessorPipeline.from_pretrained(
        folder, config_filename=TO_ROBOT, to_transition=policy_action_to_transition,
        to_output=transition_to_policy_action,
    )  # fmt: skip
    (encode, normalize), (unnormalize, decode) = to_policy.steps, to_robot.steps
    unnormalize.relative_step = decode.relative_step = encode
    return PolicySpaceSteps(encode, normalize, unnormalize, decode)


def convert_checkpoint(
    policy_dir: Path | str, output: Path | str, dataset: Path | str | None = None, hand: str | None = None
) -> Path:
    """Copies the stock checkpoint folder `policy_dir` to `output` with the steps of the policy-space
    dataset it was trained on (`dataset`, else the one its train_config.json names) around its own."""
    policy_dir = Path(policy_dir)
    config = checkpoint_config(policy_dir)
    if config.type == "opfa":
        raise ValueError(f"{policy_dir} is an opfa policy: its processors already take and give joints")
    root = Path(dataset) if dataset is not None else _training_dataset(policy_dir)
    steps = load_steps(root / STEPS_DIR, hand)
    pre, post = make_pre_post_processors(config, pretrained_path=str(policy_dir))
    if any(isinstance(s, OpfaEncodeJointsStep) for s in pre.steps):
        raise ValueError(f"{policy_dir} already takes and gives joints (it was converted)")
    own = next((s for s in pre.steps if isinstance(s, RelativeActionsProcessorStep)), None)
    if own is not None:
        raise ValueError(
            f"{policy_dir}: {config.type}'s preprocessor has its own relative-action step "
            f"({type(own).__name__}), and a loaded postprocessor is paired with the first such step, so "
            f"opfa's joint steps cannot sit beside it; convert-io takes policies without one (act, diffusion)"
        )
    pre_names = [type(s).__name__ for s in pre.steps]
    post_names = [type(s).__name__ for s in post.steps]
    if "NormalizerProcessorStep" not in pre_names or "UnnormalizerProcessorStep" not in post_names:
        raise ValueError(f"expected LeRobot's (un)normaliser steps, got {pre_names} and {post_names}")
    at = pre_names.index("NormalizerProcessorStep")
    _check_trained_on(policy_dir, pre.steps[at].state_dict(), root)
    pre.steps[at:at] = [steps.encode, steps.normalize]
    at = post_names.index("UnnormalizerProcessorStep") + 1
    post.steps[at:at] = [steps.unnormalize, steps.decode]
    return write_copy(policy_dir, output, pre, post), config.output_features[ACTION].shape[0]


def _check_trained_on(policy_dir: Path, normalizer: dict[str, torch.Tensor], root: Path) -> None:
    """A stock checkpoint's normaliser holds the statistics of the latent dataset it was trained on: a
    dataset of another GaLR, other embodiments or other frames has other statistics, and its steps would
    decode the policy's actions into other joints without a word."""
    recorded = read_json(root / "meta" / "stats.json")
    for key in (OBS_STATE, ACTION):
        for stat in ("mean", "std", "min", "max"):
            saved = normalizer.get(f"{key}.{stat}")
            if saved is None or stat not in recorded.get(key, {}):
                continue
            saved, theirs = saved.double().flatten(), torch.tensor(recorded[key][stat]).double().flatten()
            off = (saved - theirs).abs().max().item() if saved.shape == theirs.shape else float("inf")
            if off > 1e-4 * max(1.0, theirs.abs().max().item()):
                raise ValueError(
                    f"{policy_dir} was not trained on {root}: its normaliser's {key} {stat} differs from the "
                    f"dataset's (by up to {off:.3g}); give --dataset the latent dataset it was trained on"
                )


def _training_dataset(policy_dir: Path) -> Path:
    train_config = policy_dir / "train_config.json"
    root = json.loads(train_config.read_text())["dataset"].get("root") if train_config.is_file() else None
    if root is None:
        raise ValueError(
            f"{policy_dir} does not say which dataset it was trained on (no train_config.json with "
            "dataset.root): pass --dataset, the latent dataset it was trained on"
        )
    return Path(root)
