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


@dataclass(frozen=True)
class Workspace:
    """The box points are kept in (world frame, metres) and the voxel size of the downsample."""

    low: tuple[float, float, float] = tuple(WORKSPACE_LOW.tolist())
    high: tuple[float, float, float] = tuple(WORKSPACE_HIGH.tolist())
    voxel: float = VOXEL


@dataclass(frozen=True)
class PinholeCamera:
    """A depth camera: OpenCV intrinsics (pixel (u, v) has centre (u, v); x right, y down, z forward) and
    the camera-to-world pose (4x4, metres)."""

    fx: float
    fy: float
    cx: float
    cy: float
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
        """A calibration YAML: `cameras: {KEY: {fx, fy, cx, cy, camera_to_world: 4x4}}`, optional
        `depth_unit` (mm) and `workspace: {low, high, voxel}`."""
        try:
            raw = read_yaml(path, "camera calibration")
        except YamlFileError as err:
            raise DepthRigError(str(err)) from None
        return cls.from_dict(raw, str(path))

    @classmethod
    def from_dict(cls, raw: Any, source: str = "<dict>") -> DepthRig:
        if not isinstance(raw, dict) or not isinstance(raw.get("cameras"), dict) or not raw["cameras"]:
            raise DepthRigError(
                f"{source}: expected a mapping with `cameras: {{KEY: {{fx, fy, cx, cy, camera_to_world}}}}`"
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

    def points(self, depths: dict[str, np.ndarray]) -> np.ndarray:
        """World points (P, 3) of one frame of every camera ((H, W) depth in `depth_unit`), uncropped."""
        scale, floor = DEPTH_UNITS[self.depth_unit], self.workspace.low[2]
        clouds = []
        for key, camera in self.cameras.items():
            depth = np.asarray(depths[key], dtype=np.float64) * scale
            clouds.append(back_project(depth, camera, _rays(camera, *depth.shape), floor))
        return np.concatenate(clouds)

    def cloud(self, depths: dict[str, np.ndarray], n_points: int, rng: np.random.Generator) -> np.ndarray:
        """The policy's cloud (n_points, 3) of one frame; a frame that puts no point in the workspace is an
        error (a wrong pose, unit or crop would otherwise give the policy a cloud of zeros)."""
        points = crop(self.points(depths), self.workspace)
        if len(points) == 0:
            raise DepthRigError(
                f"the depth frames of {', '.join(self.cameras)} put no point in the workspace "
                f"{list(self.workspace.low)}..{list(self.workspace.high)} (check each camera's "
                f"camera_to_world, the depth_unit '{self.depth_unit}' and the workspace in {self.source})"
            )
        return downsample(points, n_points, rng, self.workspace)


@functools.lru_cache(maxsize=16)
def _rays(camera: PinholeCamera, height: int, width: int) -> np.ndarray:
    return camera.rays(height, width)


def _camera(key: str, raw: Any, source: str) -> PinholeCamera:
    """One camera's entry: intrinsics and a rigid 4x4 camera-to-world pose."""
    fields = ("fx", "fy", "cx", "cy", "camera_to_world")
    if not isinstance(raw, dict) or sorted(raw) != sorted(fields):
        given = sorted(raw) if isinstance(raw, dict) else type(raw).__name__
        raise DepthRigError(f"{source}: camera '{key}' needs exactly {list(fields)}, got {given}")
    try:
        pose = np.asarray(raw["camera_to_world"], dtype=np.float64)
        fx, fy, cx, cy = (float(raw[f]) for f in fields[:4])
    except (TypeError, ValueError):
        raise DepthRigError(f"{source}: camera '{key}' has non-numeric intrinsics or pose") from None
    rigid = (
        pose.shape == (4, 4)
        and np.allclose(pose[3], [0, 0, 0, 1])
        and np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-4)
    )
    if not rigid:
        raise DepthRigError(
            f"{source}: camera '{key}' camera_to_world must be a rigid 4x4 pose (rotation, translation)"
        )
    if fx <= 0 or fy <= 0:
        raise DepthRigError(f"{source}: camera '{key}' needs positive fx and fy (pixels)")
    return PinholeCamera(fx, fy, cx, cy, tuple(map(tuple, pose.tolist())))
