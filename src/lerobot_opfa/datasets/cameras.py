"""The cameras of a merge: which camera of each input is which camera of the merged dataset.

Without a camera map, a camera is merged where every input has one under the same key, of the same size
and kind. A camera map (`--camera-map front=observation.images.cam_high front=observation.images.top`) names
roles: each input's camera among a role's keys becomes the merged `observation.images.<role>`, at the size
the first input that has it records (colour pictures of another size are resized; depth maps are not, as
their intrinsics would no longer describe them). An input with no camera of a role gets a blank picture and
`camera_missing.<role>` true in its frames: a mask a policy or a filter can read, not a blank passed off as
a picture."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from lerobot.utils.constants import OBS_IMAGES

CAMERA_DTYPES = ("image", "video")
MISSING_PREFIX = "camera_missing."
"""The mask feature of a role some input has no camera of: `camera_missing.<role>`, (1,) bool."""


@dataclass(frozen=True)
class Camera:
    key: str
    """The merged feature."""
    feature: dict
    sources: dict[Path, str | None]
    """Per input, the key of its camera (None: it has none)."""

    @property
    def mask_key(self) -> str | None:
        """The mask feature, where some input has no camera of this one."""
        role = self.key.removeprefix(f"{OBS_IMAGES}.")
        return f"{MISSING_PREFIX}{role}" if None in self.sources.values() else None


def parse_camera_map(items: list[str]) -> dict[str, list[str]]:
    """`ROLE=KEY` items -> role -> the keys inputs record it under (a role given once per key)."""
    roles: dict[str, list[str]] = {}
    for item in items:
        role, _, key = item.partition("=")
        if not role or not key or "." in role or "/" in role:
            raise ValueError(
                f"--camera-map {item}: ROLE=KEY, a role name without dots (front) and a camera feature of "
                "the inputs (observation.images.cam_high)"
            )
        roles.setdefault(role, []).append(key)
    return roles


def is_depth(feature: dict) -> bool:
    return bool((feature.get("info") or {}).get("is_depth_map"))


def _merged_feature(feature: dict, recorded: list[dict]) -> dict:
    """The merged camera of a role shaped as `feature`: video where any input keeps the role as video (a
    dataset of many frames stays the size it was recorded at), else pictures."""
    video = any(f["dtype"] == "video" for f in recorded)
    return {"dtype": "video" if video else "image", "shape": tuple(feature["shape"]),
            "names": feature["names"], "info": {"is_depth_map": is_depth(feature)}}  # fmt: skip


def plan_cameras(inputs: dict[Path, dict], camera_map: dict[str, list[str]]) -> list[Camera]:
    """The merged cameras of inputs with LeRobot `features` (by root): the roles of `camera_map`, then
    every other camera all inputs record under one key alike; a mapped camera no input has, one input
    with two cameras of a role, and cameras of one role that disagree in kind (or depth in size) are
    errors naming them."""
    roots = list(inputs)
    cameras, mapped = [], {key for keys in camera_map.values() for key in keys}
    for role, keys in camera_map.items():
        sources: dict[Path, str | None] = {}
        for root, features in inputs.items():
            found = [key for key in keys if features.get(key, {}).get("dtype") in CAMERA_DTYPES]
            if len(found) > 1:
                raise ValueError(
                    f"--camera-map {role}: {root} records it twice ({', '.join(found)}); map one"
                )
            sources[root] = found[0] if found else None
        recorded = {root: inputs[root][key] for root, key in sources.items() if key is not None}
        if not recorded:
            raise ValueError(
                f"--camera-map {role}: no input has a camera {' or '.join(keys)}; the inputs' cameras: "
                + "; ".join(f"{root}: {', '.join(_camera_keys(f)) or 'none'}" for root, f in inputs.items())
            )
        first = next(iter(recorded.values()))
        kinds = {root: (is_depth(f), tuple(f["shape"])) for root, f in recorded.items()}
        if len({depth for depth, _ in kinds.values()}) > 1 or (
            is_depth(first) and len(set(kinds.values())) > 1
        ):
            found = ", ".join(f"{root}: {shape}{' depth' if d else ''}" for root, (d, shape) in kinds.items())
            raise ValueError(
                f"--camera-map {role}: its cameras disagree ({found}); a role is colour or depth in every "
                "input, and depth maps are merged at the size they were recorded (their intrinsics say it)"
            )
        cameras.append(Camera(f"{OBS_IMAGES}.{role}", _merged_feature(first, [*recorded.values()]), sources))
    for key, feature in inputs[roots[0]].items():
        if key in mapped or feature["dtype"] not in CAMERA_DTYPES:
            continue
        if not all(key in features for features in inputs.values()):
            continue
        kinds = {root: (tuple(f[key]["shape"]), is_depth(f[key])) for root, f in inputs.items()}
        if len(set(kinds.values())) > 1:
            found = ", ".join(f"{root}: {shape}{' depth' if d else ''}" for root, (shape, d) in kinds.items())
            raise ValueError(
                f"the inputs disagree on camera '{key}' ({found}); record them alike, or name them one role "
                f"with --camera-map ROLE={key} (colour pictures are then resized)"
            )
        recorded = [features[key] for features in inputs.values()]
        cameras.append(Camera(key, _merged_feature(feature, recorded), dict.fromkeys(roots, key)))
    return cameras


def _camera_keys(features: dict) -> list[str]:
    return [key for key, feature in features.items() if feature["dtype"] in CAMERA_DTYPES]


def camera_features(cameras: list[Camera]) -> dict[str, dict]:
    """The merged features of `cameras` and of their masks."""
    out = {camera.key: camera.feature for camera in cameras}
    for camera in cameras:
        if camera.mask_key is not None:
            out[camera.mask_key] = {"dtype": "bool", "shape": (1,), "names": None}
    return out


def camera_frame(cameras: list[Camera], root: Path, item: dict | None) -> dict[str, np.ndarray]:
    """One merged frame's cameras (and masks) from input `root`'s frame `item` as LeRobot serves it."""
    out = {}
    for camera in cameras:
        key = camera.sources[root]
        height, width, channels = camera.feature["shape"]
        if key is None:
            dtype = np.uint16 if is_depth(camera.feature) else np.uint8
            out[camera.key] = np.zeros((height, width, channels), dtype)
        else:
            image = item[key]
            if tuple(image.shape[1:]) != (height, width):  # colour only (`plan_cameras`)
                image = torch.nn.functional.interpolate(
                    image[None].float(), size=(height, width), mode="bilinear", antialias=True
                )[0]
            out[camera.key] = recorded_frame(image, camera.feature)
        if camera.mask_key is not None:
            out[camera.mask_key] = np.array([key is None])
    return out


def recorded_frame(image: torch.Tensor, feature: dict) -> np.ndarray:
    """A frame as LeRobot serves it ((C, H, W): RGB in [0, 1], depth in mm) -> as a robot records it
    ((H, W, C): uint8 RGB, uint16 mm depth)."""
    hwc = image.permute(1, 2, 0).numpy()
    if is_depth(feature):
        return np.round(hwc).clip(0, 65535).astype(np.uint16)
    return np.round(hwc * 255).clip(0, 255).astype(np.uint8)
