"""Cameras recorded under other names and sizes merge as one camera (`--camera-map`): each input's
camera of a role becomes `observation.images.<role>`, colour resized to the first input's size, and an input
with none gets a blank picture and `camera_missing.<role>` true, not a blank passed off as a picture."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_opfa import cli
from lerobot_opfa.datasets.io import new_dataset
from lerobot_opfa.datasets.layout import OPFA_META_FILE
from lerobot_opfa.datasets.merge import merge_datasets
from lerobot_opfa.datasets.synthetic import WRIST_NAMES

NAMES = [*WRIST_NAMES, "left_jaw_joint"]


def picture(height: int, width: int, frame: int) -> np.ndarray:
    """A smooth picture (a gradient shifted by the frame), so resizing it keeps it close to the original."""
    y, x = np.mgrid[0:height, 0:width]
    rgb = np.stack([x / width, y / height, np.full_like(x, frame / 10.0, dtype=float)], axis=-1)
    return (255 * rgb).astype(np.uint8)


def record(root: Path, cameras: dict[str, tuple[int, int]], frames: int = 4, video: bool = False) -> Path:
    """A umi dataset with colour cameras `cameras` (key -> (height, width)), as pictures or as video."""
    kind = "video" if video else "image"
    features = {
        OBS_STATE: {"dtype": "float32", "shape": (len(NAMES),), "names": NAMES},
        ACTION: {"dtype": "float32", "shape": (len(NAMES),), "names": NAMES},
        **{key: {"dtype": kind, "shape": (h, w, 3), "names": ["height", "width", "channels"]}
           for key, (h, w) in cameras.items()},
    }  # fmt: skip
    create = dict(repo_id=f"local/{root.name}", fps=10, features=features, robot_type="umi", use_videos=video)
    state = np.array([0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.02], np.float32)
    with new_dataset(root, **create) as dataset:
        for t in range(frames):
            images = {key: picture(h, w, t) for key, (h, w) in cameras.items()}
            dataset.add_frame({OBS_STATE: state, ACTION: state, **images, "task": "look"})
        dataset.save_episode()
    return root


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("cameras")
    return {
        "high": record(root / "high", {"observation.images.cam_high": (48, 64)}),
        "top": record(root / "top", {"observation.images.top": (24, 32)}),
        "none": record(root / "none", {"observation.images.wrist": (24, 32)}),
    }


def test_cameras_of_other_names_and_sizes_merge_as_one_role_and_a_robot_without_one_is_masked(
    inputs, tmp_path
):
    roles = ["front=observation.images.cam_high", "front=observation.images.top"]
    out = merge_datasets(list(inputs.values()), tmp_path / "merged", camera_map=roles)
    merged = LeRobotDataset("local/merged", root=out)
    assert merged.meta.features["observation.images.front"]["shape"] == (48, 64, 3)
    assert "observation.images.cam_high" not in merged.meta.features
    assert merged.meta.features["camera_missing.front"]["dtype"] == "bool"
    frames = {int(merged[i]["episode_index"]): merged[i] for i in range(0, len(merged), 4)}
    high, top, none = (frames[e] for e in range(3))
    expected = picture(48, 64, 0).transpose(2, 0, 1) / 255
    assert np.abs(high["observation.images.front"].numpy() - expected).max() <= 1 / 255 + 1e-6
    assert np.abs(top["observation.images.front"].numpy() - expected).max() < 0.05, "resized from 24x32"
    assert [bool(f["camera_missing.front"]) for f in (high, top, none)] == [False, False, True]
    assert none["observation.images.front"].abs().max() == 0
    record = json.loads((out / OPFA_META_FILE).read_text())["camera_sources"]["observation.images.front"]
    assert list(record.values()) == ["observation.images.cam_high", "observation.images.top", None]


def test_cameras_recorded_as_video_stay_video(inputs, tmp_path):
    """A role any input keeps as video is written as video (encoded once per episode), not as one picture
    file per frame; its frames read back as recorded, within the codec's loss."""
    video = record(tmp_path / "video", {"observation.images.top": (48, 64)}, frames=12, video=True)
    roles = ["front=observation.images.cam_high", "front=observation.images.top"]
    out = merge_datasets([video, inputs["high"]], tmp_path / "merged", camera_map=roles)
    merged = LeRobotDataset("local/merged", root=out)
    assert merged.meta.features["observation.images.front"]["dtype"] == "video"
    assert merged.meta.video_keys == ["observation.images.front"] and not list(out.rglob("*.png"))
    assert len(list((out / "videos").rglob("*.mp4"))) >= 1
    for index, frame in ((0, 0), (11, 11), (12, 0)):  # the video input's frames, then the pictures'
        expected = picture(48, 64, frame).transpose(2, 0, 1) / 255
        assert np.abs(merged[index]["observation.images.front"].numpy() - expected).mean() < 0.02


def test_without_a_map_cameras_of_other_sizes_are_named_with_the_fix(inputs, tmp_path):
    top = record(tmp_path / "top_big", {"observation.images.top": (48, 64)})
    with pytest.raises(ValueError, match=r"disagree on camera 'observation.images.top' .*--camera-map ROLE="):
        merge_datasets([inputs["top"], top], tmp_path / "merged")


@pytest.mark.parametrize(
    "roles, message",
    [
        (["front=observation.images.nowhere"], r"front: no input has a camera observation.images.nowhere"),
        (["front=observation.images.top", "front=observation.images.wrist"], None),
        (["front.left=observation.images.top"], r"ROLE=KEY, a role name without dots"),
    ],
)
def test_a_camera_map_that_cannot_be_read_is_one_line(inputs, tmp_path, capsys, roles, message):
    both = record(
        tmp_path / "both", {"observation.images.top": (24, 32), "observation.images.wrist": (24, 32)}
    )
    message = (
        message or rf"front: {both} records it twice \(observation.images.top, observation.images.wrist\)"
    )
    with pytest.raises(ValueError, match=message):
        merge_datasets([inputs["top"], both], tmp_path / "merged", camera_map=roles)
    merge = ["dataset", "merge", "--inputs", str(inputs["top"]), str(both), "--output", str(tmp_path / "m"),
             "--camera-map", *roles]  # fmt: skip
    capsys.readouterr()  # the inputs' writing
    assert cli.main(merge) == 2
    err = capsys.readouterr().err
    assert len([line for line in err.splitlines() if line.startswith("error: ")]) == 1
    assert "Traceback" not in err
    assert not (tmp_path / "m").exists()
