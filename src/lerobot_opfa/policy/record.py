"""The robot record of a policy, resolved from its training dataset: the embodiments, wrist names,
robots and their joint maps (the dataset's layout), the hands' universal joints and the frozen GaLR. The
policy and its processors are built from it, each from the same dataset."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from pathlib import Path
from typing import Any

from lerobot_opfa.datasets.joint_map import JointMap
from lerobot_opfa.datasets.layout import DatasetLayout, opfa_record, read_layout
from lerobot_opfa.galr import checkpoints
from lerobot_opfa.galr.frozen import galr_fingerprint, known_hand_refs, load_galr
from lerobot_opfa.galr.model import Galr
from lerobot_opfa.hands.registry import load_spec
from lerobot_opfa.policy.configuration_opfa import OpfaConfig

logger = logging.getLogger(__name__)


def policy_galr(config: OpfaConfig, dataset_root: Path | str | None = None) -> tuple[str | None, Galr | None]:
    """The frozen GaLR of a `galr` policy and the checkpoint it is (None, None for another space). Without
    `--policy.galr_path` it is the one the dataset's cached latents came from, else the packaged default
    (`resolve_config` saves the choice with the policy). A given checkpoint that did not make the dataset's
    latents is an error."""
    if not config.space.uses_galr:
        return None, None
    record = opfa_record(dataset_root)
    path = config.galr_path
    if not path:
        recorded = bool(record.get("galr_fingerprint"))
        path = _recorded_galr(record) if recorded else checkpoints.DEFAULT
        source = "the one the dataset's latents came from" if recorded else "the default"
        logger.info(f"GaLR checkpoint: {path} ({source}; --policy.galr_path chooses another)")
    galr = load_galr(str(path))
    if record.get("galr_fingerprint") not in (None, galr_fingerprint(galr)):
        raise ValueError(
            f"--policy.galr_path={path} is not the GaLR the dataset's latents were cached with "
            f"({record.get('galr')}); leave the flag out to use that one, or merge the demos again with "
            f"--galr {path}"
        )
    return str(path), galr


def _recorded_galr(record: dict) -> str:
    """The merge's GaLR as recorded, or a packaged checkpoint with its fingerprint (a path recorded on
    another machine, or relative to another folder, is found again that way)."""
    with contextlib.suppress(ValueError):
        if galr_fingerprint(load_galr(record["galr"])) == record["galr_fingerprint"]:
            return record["galr"]
    for name in checkpoints.PACKAGED:
        if galr_fingerprint(load_galr(name)) == record["galr_fingerprint"]:
            return name
    raise ValueError(
        f"the dataset's latents were cached with GaLR '{record['galr']}', which is not here (and no packaged "
        "checkpoint has its weights); pass --policy.galr_path"
    )


def resolve_config(config: OpfaConfig, dataset_meta: Any) -> tuple[OpfaConfig, DatasetLayout, Galr | None]:
    """The policy's record resolved from a dataset: a copy of `config` with the fields it derives from the
    dataset (embodiments, wrist names, robots, their hands' universal joints, the GaLR and its latent size),
    the dataset's layout and the policy's frozen GaLR (`policy_galr`). `config` itself is left as it is."""
    galr_path, galr = policy_galr(config, dataset_meta.root)
    layout = read_layout(
        dataset_meta.features,
        dataset_meta.robot_type,
        dataset_meta.root,
        hands=known_hand_refs(galr),
        joint_map=JointMap.load(config.joint_map) if config.joint_map else None,
    )
    if config.joint_map and layout.kind == "merged":
        raise ValueError(
            f"--policy.joint_map: {dataset_meta.root} is a merged dataset, which holds the joint maps of its "
            "inputs; give the map to `lerobot-opfa dataset merge --joint-maps` instead"
        )
    if config.embodiments and config.embodiments != layout.embodiments:
        raise ValueError(
            f"this policy was built for embodiments {config.embodiments}; "
            f"the dataset holds {layout.embodiments}"
        )
    if galr is not None:
        unknown = [h for h in layout.embodiments if h not in galr.config.hand_names]
        if unknown:
            raise ValueError(
                f"hand(s) {unknown} are not in the GaLR registry of {galr_path} "
                f"({', '.join(galr.config.hand_names)}); add them with `lerobot-opfa galr pretrain --init "
                f"{galr_path} --hands +SPEC` (minutes), or use action_space raw or per_embodiment"
            )
    config.space.check_robots(layout.robots, layout.embodiments)
    resolved = dataclasses.replace(
        config,
        input_features=dict(config.input_features or {}),
        output_features=dict(config.output_features or {}),
        galr_path=galr_path if galr is not None else config.galr_path,
        latent_dim=galr.config.latent_dim if galr is not None else config.latent_dim,
        embodiments=list(layout.embodiments),
        wrist_names=list(layout.wrist_names),
        robots=[list(robot) for robot in layout.robots],
        action_body_names=None if layout.action_body_names is None else list(layout.action_body_names),
        embodiment_joints=[load_spec(ref).universal_names for ref in layout.hand_refs],
    )
    return resolved, layout, galr
