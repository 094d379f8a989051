"""World-frame point clouds from depth images: back-projection through a pinhole camera, fusion of cameras,
a crop to the workspace box and a downsample to a fixed N (voxel grid, then a uniform draw). The simulator's
depth cameras and the depth processor step (a real rig's cameras, LeRobot depth-map features) both go
through here, so a policy sees the same kind of cloud from either."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Workspace crop (world frame) of the benchmark: above the table top, inside the table's footprint.
WORKSPACE_LOW = np.array([-0.45, -0.40, 0.004])
WORKSPACE_HIGH = np.array([0.45, 0.40, 0.60])
VOXEL = 0.004
PREDRAW = 3  # before the voxel grid, keep at most this many points per output point (bounds its cost)


@dataclass(frozen=True)
class Workspace:
    """The box points are kept in (world frame, metres) and the voxel size of the downsample."""

    low: tuple[float, float, float] = tuple(WORKSPACE_LOW)
    high: tuple[float, float, float] = tuple(WORKSPACE_HIGH)
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
    lo, hi = np.asarray(workspace.low), np.asarray(workspace.high)
    x, y, z = points.T  # per-coordinate tests: several times faster than a reduction over axis 1
    points = points[(z > lo[2]) & (z < hi[2]) & (x > lo[0]) & (x < hi[0]) & (y > lo[1]) & (y < hi[1])]
    if len(points) == 0:
        return np.zeros((n_points, 3), np.float32)
    if len(points) > PREDRAW * n_points:
        points = points[rng.choice(len(points), PREDRAW * n_points, replace=False)]
    cells = np.floor((points - lo) / workspace.voxel).astype(np.int64)
    span = cells.max(0) + 1
    keys = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    _, first = np.unique(keys, return_index=True)
    points = points[first]
    index = rng.choice(len(points), n_points, replace=len(points) < n_points)
    return points[index].astype(np.float32)
