"""The robot record of a policy, resolved from its training dataset: the embodiments, wrist names,
robots and their joint maps (the dataset's layout), the hands' universal joints and the frozen GaLR. The
policy and its processors are built from it, each from the same dataset."""

from __future__ import annotations

import contextlib
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


def policy_galr(config: OpfaConfig, dataset_root: Path | str | None = None) -> Galr | None:
    """The frozen GaLR of a `galr` policy. Without `--policy.galr_path` it is the one the dataset's cached
    latents came from, else the packaged default; the choice is written into the config (and so saved with
    the policy). A given checkpoint that did not make the dataset's latents is an error."""
    if not config.space.uses_galr:
        return None
    record = opfa_record(dataset_root)
    if not config.galr_path:
        recorded = bool(record.get("galr_fingerprint"))
        config.galr_path = _recorded_galr(record) if recorded else checkpoints.DEFAULT
        source = "the one the dataset's latents came from" if recorded else "the default"
        logger.info(f"GaLR checkpoint: {config.galr_path} ({source}; --policy.galr_path chooses another)")
    galr = load_galr(str(config.galr_path))
    if record.get("galr_fingerprint") not in (None, galr_fingerprint(galr)):
        raise ValueError(
            f"--policy.galr_path={config.galr_path} is not the GaLR the dataset's latents were cached with "
            f"({record.get('galr')}); leave the flag out to use that one, or merge the demos again with "
            f"--galr {config.galr_path}"
        )
    return galr


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


def resolve_config(config: OpfaConfig, dataset_meta: Any) -> tuple[DatasetLayout, Galr | None]:
    """Fill the config's dataset-derived fields (embodiments, wrist names, latent size) from a dataset;
    returns its layout and the policy's frozen GaLR (`policy_galr`)."""
    galr = policy_galr(config, dataset_meta.root)
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
                f"hand(s) {unknown} are not in the GaLR registry of {config.galr_path} "
                f"({', '.join(galr.config.hand_names)}); add them with `lerobot-opfa galr pretrain --init "
                f"{config.galr_path} --hands +SPEC` (minutes), or use action_space raw or per_embodiment"
            )
        config.latent_dim = galr.config.latent_dim
    config.space.check_robots(layout.robots, layout.embodiments)
    config.embodiments, config.wrist_names = list(layout.embodiments), list(layout.wrist_names)
    config.robots = [list(robot) for robot in layout.robots]
    config.action_body_names = None if layout.action_body_names is None else list(layout.action_body_names)
    config.embodiment_joints = [load_spec(ref).universal_names for ref in layout.hand_refs]
    return layout, galr
