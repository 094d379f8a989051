"""`lerobot-opfa dataset latent`: a merged dataset whose state and action *are* wrist + z, so that any stock
LeRobot policy (diffusion, act, ...) trains in GaLR space without knowing about hands.

The latents are the merge's cache; at inference `convert_policy_io` wraps the trained policy's processors
with the joints<->latent steps (`policy.stock_io`)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.utils.constants import ACTION, OBS_STATE
from tqdm import tqdm

from lerobot_opfa.datasets.io import check_dataset_folder, check_outside_inputs, new_dataset, read_columns
from lerobot_opfa.datasets.layout import (
    LATENT_ROBOT_TYPE,
    OPFA_META_FILE,
    latent_names,
    opfa_record,
    read_layout,
)
from lerobot_opfa.datasets.merge import BOOKKEEPING, NUMERIC
from lerobot_opfa.hands.universal import UNIVERSAL_JOINT_NAMES

logger = logging.getLogger(__name__)


def latent_dataset(source: Path | str, output: Path | str, overwrite: bool = False) -> Path:
    """Writes `output` (atomically): `source`'s frames with state/action = wrist + cached z."""
    (source,) = check_outside_inputs([source], output)
    check_dataset_folder(source)
    meta = LeRobotDatasetMetadata(f"local/{source.name}", root=source)
    layout = read_layout(meta.features, meta.robot_type, source)
    if layout.kind != "merged" or not layout.latent_dim:
        raise ValueError(f"{source} is not a merged dataset with cached latents (merge it with --galr)")
    wrist = len(layout.wrist_names)
    keep = list(range(wrist)) + list(
        range(wrist + len(UNIVERSAL_JOINT_NAMES), wrist + len(UNIVERSAL_JOINT_NAMES) + layout.latent_dim)
    )
    names = [*layout.wrist_names, *latent_names(layout.latent_dim)]
    extra = [
        k
        for k, f in meta.features.items()
        if k not in (OBS_STATE, ACTION, *BOOKKEEPING) and f["dtype"] in NUMERIC
    ]
    features = {k: {**meta.features[k], "shape": tuple(meta.features[k]["shape"])} for k in extra}
    features |= {
        key: {"dtype": "float32", "shape": (len(names),), "names": names} for key in (OBS_STATE, ACTION)
    }
    columns = read_columns(source, [OBS_STATE, ACTION, *extra, *BOOKKEEPING])
    tasks = {int(row.task_index): task for task, row in meta.tasks.iterrows()}
    create = dict(
        repo_id=f"local/{Path(output).name}", fps=meta.fps, features=features, robot_type=LATENT_ROBOT_TYPE,
        use_videos=False,
    )  # fmt: skip
    with new_dataset(output, overwrite, **create) as dataset:
        partial = dataset.root
        episodes = columns["episode_index"]
        for episode in tqdm(list(dict.fromkeys(episodes.tolist())), desc="latent dataset", unit="episode"):
            rows = np.flatnonzero(episodes == episode)
            for row in rows[np.argsort(columns["frame_index"][rows])]:
                frame = {key: columns[key][row][keep].astype(np.float32) for key in (OBS_STATE, ACTION)}
                for key in extra:
                    frame[key] = np.asarray(columns[key][row], dtype=features[key]["dtype"]).reshape(
                        features[key]["shape"]
                    )
                frame["task"] = tasks[int(columns["task_index"][row])]
                dataset.add_frame(frame)
            dataset.save_episode()
        dataset.finalize()
        record = {**opfa_record(source), "latent_only": True}
        (partial / OPFA_META_FILE).write_text(json.dumps(record, indent=2))
    return Path(output)
