"""`lerobot-opfa dataset clouds`: a depth dataset's clouds made once, through the depth step itself, into a
numeric dataset (state, action, `observation.pointcloud`, the other numeric features), which
`lerobot-opfa train` holds in memory: decoding two frames of depth video for every sample of every step is
most of a training step otherwise. The calibration is recorded (`meta/opfa.json` `cameras`), so a policy
trained on it still takes a robot's depth frames through the same step."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from tqdm import tqdm

from lerobot_opfa.datasets.io import check_dataset_folder, check_outside_inputs, new_dataset, read_columns
from lerobot_opfa.datasets.layout import OPFA_META_FILE, opfa_record
from lerobot_opfa.datasets.merge import BOOKKEEPING, NUMERIC
from lerobot_opfa.features import OBS_POINTCLOUD
from lerobot_opfa.pointclouds import DepthRig, DepthRigError

CLOUDS_OF_DEPTH = "opfa_clouds_of_depth"
"""The point-cloud feature's `info` entry naming the depth cameras its clouds were made from: LeRobot's
editing tools keep a feature's entry where they drop `meta/opfa.json`, so a lost calibration is noticed."""


def cloud_dataset(
    source: Path | str, output: Path | str, cameras: Path | str, n_points: int = 1024, overwrite: bool = False
) -> Path:
    """Writes `output` (atomically): `source`'s numeric frames plus the cloud of each frame's depth."""
    (source,) = check_outside_inputs([source], output)
    check_dataset_folder(source)
    frames = LeRobotDataset(f"local/{source.name}", root=source)
    rig = DepthRig.load(cameras)
    rig.check_keys(frames.meta.features, str(source))
    try:
        rig.check_frame(frames[0])
    except DepthRigError as err:
        raise DepthRigError(f"{source}, frame 0: {err}") from None
    rng = np.random.default_rng(0)
    numeric = [k for k, f in frames.meta.features.items() if f["dtype"] in NUMERIC and k not in BOOKKEEPING]
    features = {
        k: {**frames.meta.features[k], "shape": tuple(frames.meta.features[k]["shape"])} for k in numeric
    }
    features[OBS_POINTCLOUD] = {"dtype": "float32", "shape": (3 * n_points,), "names": None,
                                "info": {CLOUDS_OF_DEPTH: list(rig.cameras)}}  # fmt: skip
    columns = read_columns(source, [*numeric, *BOOKKEEPING])
    position = {int(index): i for i, index in enumerate(frames.hf_dataset["index"])}
    tasks = {int(row.task_index): task for task, row in frames.meta.tasks.iterrows()}
    create = dict(repo_id=f"local/{Path(output).name}", fps=frames.meta.fps, features=features,
                  robot_type=frames.meta.robot_type, use_videos=False)  # fmt: skip
    with new_dataset(output, overwrite, **create) as dataset:
        episodes = columns["episode_index"]
        with tqdm(total=len(episodes), desc="depth to clouds", unit="frame") as progress:
            for episode in dict.fromkeys(episodes.tolist()):
                rows = np.flatnonzero(episodes == episode)
                for row in rows[np.argsort(columns["frame_index"][rows])]:
                    item = frames[position[int(columns["index"][row])]]
                    cloud = rig.clouds({k: item[k] for k in rig.cameras}, n_points, rng)
                    frame = {k: _value(columns[k][row], features[k]) for k in numeric}
                    frame[OBS_POINTCLOUD] = cloud.astype(np.float32)
                    frame["task"] = tasks[int(columns["task_index"][row])]
                    dataset.add_frame(frame)
                    progress.update()
                dataset.save_episode()
        dataset.finalize()
        record = opfa_record(source) | {"cameras": rig.to_dict(), "clouds_of": str(source)}
        (dataset.root / OPFA_META_FILE).write_text(json.dumps(record, indent=2))
    return Path(output)


def recorded_cameras(root: Path | str | None) -> dict | None:
    """The calibration a dataset's clouds were made with (`cloud_dataset`), if they were."""
    return opfa_record(root).get("cameras")


def recorded_rig(meta: LeRobotDatasetMetadata) -> DepthRig | None:
    """The calibration a dataset's clouds were made with, or None for clouds made without one (the
    simulator's, or a merge of clouds made with different calibrations, which warned). Clouds made from
    depth frames by `cloud_dataset` whose record is gone (and the calibration with it) are refused: a policy
    trained on them could not take a robot's depth frames, and would fail only at deployment."""
    record = opfa_record(meta.root)
    if record.get("cameras") is not None:
        return DepthRig.from_dict(record["cameras"], f"{Path(meta.root) / OPFA_META_FILE} `cameras`")
    depth = ((meta.features.get(OBS_POINTCLOUD) or {}).get("info") or {}).get(CLOUDS_OF_DEPTH)
    if depth and not record:
        raise DepthRigError(
            f"{meta.root}: its clouds were made from the depth cameras {depth} (`lerobot-opfa dataset "
            f"clouds`), but it lost its record ({OPFA_META_FILE}) and their calibration with it, as after an "
            "edit by LeRobot's tools: put that file back from the dataset it was made from, or make the "
            "clouds again from the edited depth dataset"
        )
    return None


def _value(value, feature: dict) -> np.ndarray:
    return np.asarray(value, dtype=feature["dtype"]).reshape(feature["shape"])
