"""World-frame point clouds from depth images: back-projection through a pinhole camera, fusion of cameras,
a crop to the workspace box and a downsample to a fixed N (voxel grid, then a uniform draw). The simulator's
depth cameras and the depth processor step (a real rig's cameras, LeRobot depth-map features) both go
through here, so a policy sees the same kind of cloud from either."""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lerobot_opfa.yaml_files import YamlFileError, read_yaml

# Workspace crop (world frame) of the benchmark: above the table top, inside the table's footprint.
WORKSPACE_LOW = np.array([-0.45, -0.40, 0.004])
WORKSPACE_HIGH = np.array([0.45, 0.40, 0.60])
VOXEL = 0.004
PREDRAW = 3  # before the voxel grid, keep at most this many points per output point (bounds its cost)
MAX_FIELD_OF_VIEW = 170.0
"""Degrees, across either image axis: a wider view is a focal length not given in pixels (in millimetres,
fx = 1.93 spreads a 128-pixel row over 176 degrees)."""
MIN_VOXELS = 32
"""Occupied workspace voxels a dataset's first frame must give: fewer (a wrong depth unit, a pose that looks
past the table) is not a scene the policy can read."""
MIN_INSIDE_SHARE = 0.5
"""A camera whose points above the workspace floor land mostly outside the workspace, where its inverse pose
lands most of them inside, was given world-to-camera (the simulated rig's cameras: 100 % inside; inverted,
19-40 %)."""


@dataclass(frozen=True)
class Workspace:
    """The box points are kept in (world frame, metres) and the voxel size of the downsample."""

    low: tuple[float, float, float] = tuple(WORKSPACE_LOW.tolist())
    high: tuple[float, float, float] = tuple(WORKSPACE_HIGH.tolist())
    voxel: float = VOXEL


@dataclass(frozen=True)
class PinholeCamera:
    """A depth camera: OpenCV intrinsics (pixel (u, v) has centre (u, v); x right, y down, z forward) of
    images of `width` x `height` pixels, the only size they hold for, and the camera-to-world pose (4x4,
    metres)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    camera_to_world: tuple[tuple[float, ...], ...]

    def rays(self, height: int, width: int) -> np.ndarray:
        """(H*W, 3) camera-frame rays of the pixels at unit depth (z = 1)."""
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        rays = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)], axis=-1)
        return rays.reshape(-1, 3)


def back_project(depth: np.ndarray, camera: PinholeCamera, rays: np.ndarray, floor: float) -> np.ndarray:
    """World points (P, 3) of a depth image (H, W) in metres along the optical axis; pixels without a
    return (0, NaN) and points below `floor` (most pixels see the table) are left out before the full
    transform, which is most of the cost."""
    pose = np.asarray(camera.camera_to_world, dtype=np.float64)
    rot, pos = pose[:3, :3], pose[:3, 3]
    depth = depth.reshape(-1)
    keep = (depth > 0) & (depth * (rays @ rot[2]) + pos[2] > floor)
    return (rays[keep] * depth[keep, None]) @ rot.T + pos


def crop_and_downsample(
    points: np.ndarray, n_points: int, rng: np.random.Generator, workspace: Workspace = Workspace()
) -> np.ndarray:
    """Keep the points inside the workspace, one per voxel, then draw exactly `n_points` of them."""
    return downsample(crop(points, workspace), n_points, rng, workspace)


def crop(points: np.ndarray, workspace: Workspace = Workspace()) -> np.ndarray:
    """The points inside the workspace box."""
    lo, hi = workspace.low, workspace.high
    x, y, z = points.T  # per-coordinate tests: several times faster than a reduction over axis 1
    return points[(z > lo[2]) & (z < hi[2]) & (x > lo[0]) & (x < hi[0]) & (y > lo[1]) & (y < hi[1])]


def downsample(
    points: np.ndarray, n_points: int, rng: np.random.Generator, workspace: Workspace = Workspace()
) -> np.ndarray:
    """One point per voxel, then exactly `n_points` drawn (zeros when there is none)."""
    if len(points) == 0:
        return np.zeros((n_points, 3), np.float32)
    if len(points) > PREDRAW * n_points:
        points = points[rng.choice(len(points), PREDRAW * n_points, replace=False)]
    cells = np.floor((points - np.asarray(workspace.low)) / workspace.voxel).astype(np.int64)
    span = cells.max(0) + 1
    keys = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    _, first = np.unique(keys, return_index=True)
    points = points[first]
    index = rng.choice(len(points), n_points, replace=len(points) < n_points)
    return points[index].astype(np.float32)


class DepthRigError(ValueError):
    """A camera calibration file or a depth frame that cannot give a point cloud."""


DEPTH_UNITS = {"mm": 1e-3, "m": 1.0}
"""Depth units a rig's frames may come in, in metres: LeRobot's depth-map features and RealSense's
`read_depth` give millimetres."""


@dataclass(frozen=True)
class DepthRig:
    """A rig's depth cameras by feature key (`observation.images.<name>`), the unit of their frames and the
    workspace: everything needed to turn depth frames into the policy's cloud, saved with the checkpoint."""

    cameras: dict[str, PinholeCamera]
    depth_unit: str = "mm"
    workspace: Workspace = Workspace()
    source: str = "<dict>"

    @classmethod
    def load(cls, path: Path | str) -> DepthRig:
        """A calibration YAML: `cameras: {KEY: {fx, fy, cx, cy, width, height, camera_to_world: 4x4}}`,
        optional `depth_unit` (mm) and `workspace: {low, high, voxel}`. Each camera is checked for meaning
        (`_camera`); KEY is the dataset's feature key, `observation.images.<name>` (`check_keys`)."""
        try:
            raw = read_yaml(path, "camera calibration")
        except YamlFileError as err:
            raise DepthRigError(str(err)) from None
        return cls.from_dict(raw, str(path))

    @classmethod
    def from_dict(cls, raw: Any, source: str = "<dict>") -> DepthRig:
        if not isinstance(raw, dict) or not isinstance(raw.get("cameras"), dict) or not raw["cameras"]:
            raise DepthRigError(
                f"{source}: expected a mapping with "
                "`cameras: {KEY: {fx, fy, cx, cy, width, height, camera_to_world}}`"
            )
        unknown = sorted(set(raw) - {"cameras", "depth_unit", "workspace"})
        if unknown:
            raise DepthRigError(f"{source}: unknown keys {unknown} (expected cameras, depth_unit, workspace)")
        unit = raw.get("depth_unit", "mm")
        if unit not in DEPTH_UNITS:
            raise DepthRigError(f"{source}: depth_unit '{unit}' is not one of {list(DEPTH_UNITS)}")
        cameras = {key: _camera(key, value, source) for key, value in raw["cameras"].items()}
        space = raw.get("workspace") or {}
        workspace = Workspace(
            tuple(map(float, space.get("low", WORKSPACE_LOW))),
            tuple(map(float, space.get("high", WORKSPACE_HIGH))),
            float(space.get("voxel", VOXEL)),
        )
        if (
            not all(lo < hi for lo, hi in zip(workspace.low, workspace.high, strict=True))
            or workspace.voxel <= 0
        ):
            raise DepthRigError(f"{source}: workspace needs low < high on each axis and a positive voxel")
        return cls(cameras, unit, workspace, source)

    def to_dict(self) -> dict[str, Any]:
        return {
            "cameras": {k: {**asdict(c), "camera_to_world": [list(r) for r in c.camera_to_world]}
                        for k, c in self.cameras.items()},
            "depth_unit": self.depth_unit,
            "workspace": {"low": list(self.workspace.low), "high": list(self.workspace.high),
                          "voxel": self.workspace.voxel},
        }  # fmt: skip

    def check_keys(self, features: dict[str, Any], where: str) -> None:
        """Every calibrated camera is a feature of `where`. A key is the full feature key: a short camera name
        that happens to match one feature is refused too, as the checkpoint's step meets the robot's
        observations under the full key."""
        missing = [k for k in self.cameras if k not in features]
        if missing:
            cameras = [k for k, f in features.items() if f.get("dtype") in ("video", "image")]
            near = {k: [c for c in cameras if c.split(".")[-1] == k.split(".")[-1]] for k in missing}
            hint = "; ".join(f"'{k}' is '{v[0]}'?" for k, v in near.items() if len(v) == 1)
            raise DepthRigError(
                f"{self.source} calibrates {missing}, which {where} does not have: key each camera by its "
                f"feature key, one of {cameras or 'its cameras (it has none)'}"
                + (f" ({hint})" if hint else "")
            )

    def check_frame(self, depths: dict[str, Any]) -> None:
        """A dataset's first frame of every camera (as LeRobot or a robot serves it, `depth_frames`) shows
        the workspace: enough occupied voxels, and no camera whose inverse pose explains its frame far better
        (a pose given world-to-camera). Run before any work: a wrong calibration would otherwise train a
        policy on clouds of the wrong place."""
        depths = {key: depth_frames(depths[key], key) for key in self.cameras}
        scale = DEPTH_UNITS[self.depth_unit]
        for key, camera in self.cameras.items():
            depth = self._checked(key, camera, depths[key]) * scale
            pose = np.asarray(camera.camera_to_world)
            given, inverse = (self._inside_share(depth, camera, p) for p in (pose, np.linalg.inv(pose)))
            if given < MIN_INSIDE_SHARE <= inverse and inverse >= 2 * given:
                raise DepthRigError(
                    f"{self.source}: camera '{key}' puts {given:.0%} of its points above the workspace floor "
                    f"inside the workspace, its inverse pose {inverse:.0%}: camera_to_world looks like a "
                    "world-to-camera pose; give its inverse"
                )
        points = crop(self.points(depths), self.workspace)
        voxels = len(np.unique(np.floor((points - self.workspace.low) / self.workspace.voxel), axis=0))
        if voxels < MIN_VOXELS:
            raise self._blind(f"{voxels} occupied voxels (fewer than {MIN_VOXELS})" if voxels else "no point")

    def _inside_share(self, depth: np.ndarray, camera: PinholeCamera, pose: np.ndarray) -> float:
        """The share of a frame's points above the workspace floor that land in the workspace under `pose`."""
        valid = depth.reshape(-1) > 0
        points = (_rays(camera, *depth.shape)[valid] * depth.reshape(-1)[valid, None]) @ pose[:3, :3].T
        points += pose[:3, 3]
        above = points[points[:, 2] > self.workspace.low[2]]
        return len(crop(above, self.workspace)) / max(len(above), 1)

    def _checked(self, key: str, camera: PinholeCamera, depth: Any) -> np.ndarray:
        """A frame as float64, refused when its size is not the one the intrinsics are for."""
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != (camera.height, camera.width):
            raise DepthRigError(
                f"camera '{key}' gives depth frames of {_size(depth.shape)} (width x height), but its "
                f"calibration in {self.source} is for {camera.width}x{camera.height}: the intrinsics hold "
                "for that size only; calibrate it at the size it records (or record at the calibrated size)"
            )
        return depth

    def points(self, depths: dict[str, np.ndarray]) -> np.ndarray:
        """World points (P, 3) of one frame of every camera ((H, W) depth in `depth_unit`), uncropped."""
        scale, floor = DEPTH_UNITS[self.depth_unit], self.workspace.low[2]
        clouds = []
        for key, camera in self.cameras.items():
            depth = self._checked(key, camera, depths[key]) * scale
            clouds.append(back_project(depth, camera, _rays(camera, *depth.shape), floor))
        return np.concatenate(clouds)

    def cloud(self, depths: dict[str, np.ndarray], n_points: int, rng: np.random.Generator) -> np.ndarray:
        """The policy's cloud (n_points, 3) of one frame; a frame that puts no point in the workspace is an
        error (a wrong pose, unit or crop would otherwise give the policy a cloud of zeros)."""
        points = crop(self.points(depths), self.workspace)
        if len(points) == 0:
            raise self._blind("no point")
        return downsample(points, n_points, rng, self.workspace)

    def clouds(self, depths: dict[str, Any], n_points: int, rng: np.random.Generator) -> np.ndarray:
        """The clouds (..., n_points * 3) of frames as LeRobot or a robot serves them (`depth_frames`, any
        leading batch/history dims): what a dataset's `dataset clouds` and a policy's depth step make."""
        frames = {key: depth_frames(depths[key], key) for key in self.cameras}
        lead = next(iter(frames.values())).shape[:-2]
        if any(v.shape[:-2] != lead for v in frames.values()):
            shapes = ", ".join(f"{k}: {tuple(v.shape)}" for k, v in frames.items())
            raise DepthRigError(f"the depth frames disagree on their batch/history dims ({shapes})")
        flat = {k: v.reshape(-1, *v.shape[-2:]) for k, v in frames.items()}
        clouds = [
            self.cloud({k: v[i] for k, v in flat.items()}, n_points, rng)
            for i in range(int(np.prod(lead, dtype=np.int64)))
        ]
        return np.stack(clouds).reshape(*lead, 3 * n_points)

    def _blind(self, found: str) -> DepthRigError:
        return DepthRigError(
            f"the depth frames of {', '.join(self.cameras)} put {found} in the workspace "
            f"{list(self.workspace.low)}..{list(self.workspace.high)} (check each camera's "
            f"camera_to_world, the depth_unit '{self.depth_unit}' and the workspace in {self.source})"
        )


def depth_frames(depth: Any, key: str) -> np.ndarray:
    """Depth frames (..., H, W) as float64: LeRobot gives (..., 1, H, W) tensors, a robot (H, W, 1) arrays."""
    array = depth.detach().cpu().numpy() if hasattr(depth, "detach") else np.asarray(depth)
    if array.ndim >= 3 and array.shape[-3] == 1:
        array = array[..., 0, :, :]
    elif array.ndim == 3 and array.shape[-1] == 1:
        array = array[..., 0]
    if array.ndim < 2:
        raise DepthRigError(
            f"{key}: a depth frame needs shape (H, W), (1, H, W) or (H, W, 1), got {array.shape}"
        )
    return array.astype(np.float64)


@functools.lru_cache(maxsize=16)
def _rays(camera: PinholeCamera, height: int, width: int) -> np.ndarray:
    return camera.rays(height, width)


def _size(shape: tuple[int, ...]) -> str:
    return f"{shape[-1]}x{shape[-2]}" if len(shape) >= 2 else str(shape)


def _camera(key: str, raw: Any, source: str) -> PinholeCamera:
    """One camera's entry, checked for meaning: finite intrinsics in pixels of an image of the given size
    (principal point inside it, a field of view below `MAX_FIELD_OF_VIEW`) and a rigid, right-handed
    camera-to-world pose."""
    where = f"{source}: camera '{key}'"
    fields = ("fx", "fy", "cx", "cy", "width", "height", "camera_to_world")
    if isinstance(raw, dict) and sorted(raw) == sorted(set(fields) - {"width", "height"}):
        raise DepthRigError(
            f"{where} does not say the image size its intrinsics are for: add `width` and `height` (pixels "
            "of the depth frames it was calibrated on); frames of another size are refused"
        )
    if not isinstance(raw, dict) or sorted(raw) != sorted(fields):
        given = sorted(raw) if isinstance(raw, dict) else type(raw).__name__
        raise DepthRigError(f"{where} needs exactly {list(fields)}, got {given}")
    intrinsics = {}
    for name in fields[:4]:
        value = raw[name]
        if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
            raise DepthRigError(f"{where} {name} is {value!r}: intrinsics are finite numbers (pixels)")
        intrinsics[name] = float(value)
    fx, fy, cx, cy = intrinsics.values()
    width, height = raw["width"], raw["height"]
    if any(isinstance(n, bool) or not isinstance(n, int) or n <= 0 for n in (width, height)):
        raise DepthRigError(
            f"{where} width and height must be positive whole pixels, got {width!r}, {height!r}"
        )
    try:
        pose = np.asarray(raw["camera_to_world"], dtype=np.float64)
    except (TypeError, ValueError):
        raise DepthRigError(f"{where} camera_to_world must be a 4x4 matrix of numbers") from None
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise DepthRigError(f"{where} camera_to_world must be a 4x4 matrix of finite numbers")
    rotation = pose[:3, :3]
    if not (np.allclose(pose[3], [0, 0, 0, 1]) and np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4)):
        raise DepthRigError(f"{where} camera_to_world must be a rigid 4x4 pose (rotation, translation)")
    if np.linalg.det(rotation) < 0:
        raise DepthRigError(
            f"{where} camera_to_world is mirrored (its rotation has determinant -1, a left-handed frame): "
            "its columns are the camera's x (right), y (down) and z (forward) axes in the world; one is "
            "flipped"
        )
    if fx <= 0 or fy <= 0:
        raise DepthRigError(f"{where} needs positive fx and fy (pixels)")
    if not (-0.5 <= cx <= width - 0.5 and -0.5 <= cy <= height - 0.5):
        raise DepthRigError(
            f"{where} principal point (cx, cy) = ({cx:g}, {cy:g}) lies outside its {width}x{height} image: "
            "cx, cy are pixels of that image (about width / 2, height / 2)"
        )
    for axis, focal, centre, pixels in (("horizontal", fx, cx, width), ("vertical", fy, cy, height)):
        view = np.degrees(np.arctan((centre + 0.5) / focal) + np.arctan((pixels - 0.5 - centre) / focal))
        if view >= MAX_FIELD_OF_VIEW:
            raise DepthRigError(
                f"{where} fx={fx:g}, fy={fy:g} give a {view:.0f} degree {axis} field of view over {pixels} "
                f"pixels (at most {MAX_FIELD_OF_VIEW:.0f}): focal lengths must be in pixels (the focal "
                "length in millimetres divided by the pixel pitch in millimetres), not millimetres"
            )
    return PinholeCamera(fx, fy, cx, cy, width, height, tuple(map(tuple, pose.tolist())))
