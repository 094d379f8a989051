"""Point-cloud observations in the world frame: from simulated depth cameras (the default, what a real
rig sees) or sampled on the geometry (faster, complete). Both are cropped to the workspace above the
table and downsampled to a fixed N (`pointclouds`, the code the depth processor step runs on a rig's
cameras)."""

from __future__ import annotations

import mujoco
import numpy as np
import trimesh

from lerobot_opfa.envs.scene import HIDDEN_GROUP, RENDER_CAMERA, SCENERY_GROUP
from lerobot_opfa.hands.geometry import geom_mesh
from lerobot_opfa.pointclouds import WORKSPACE_LOW, PinholeCamera, back_project, crop_and_downsample

# Render-context settings of depth cameras; software GL pays per triangle and per sample. Round geoms coarser
# than in pictures (28 slices, 16 stacks): 12 slices put a 1 cm capsule's facets within 0.2 mm of the surface,
# far under the 4 mm voxel. Box faces (the built-in hands are made of boxes) undivided: pictures split them
# for per-vertex lighting, depth is the same. No multisampling (pictures: 4): depth read at pixel centres.
DEPTH_QUALITY = {"numslices": 12, "numstacks": 6, "numquads": 1, "offsamples": 0}


class ColourCameras:
    """Colour images (H, W, 3) uint8 of some of the scene's cameras (`scene.DEPTH_CAMERAS`, the depth
    cameras' poses): what the rig records as `<name>_rgb` and the env gives as `pixels`, from one renderer so
    that a policy trained on one sees the same pictures in the other. Shadows and reflections off: under
    software GL they make a frame several times slower."""

    def __init__(self, model: mujoco.MjModel, cameras: list[str], width: int = 128, height: int = 96) -> None:
        self.renderer = mujoco.Renderer(model, height=height, width=width)
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self.names = list(cameras)
        self.cameras = [model.camera(f"depth_{name}").id for name in cameras]

    def images(self, data: mujoco.MjData) -> dict[str, np.ndarray]:
        """Camera name -> (H, W, 3) uint8."""
        images = {}
        for name, cam in zip(self.names, self.cameras, strict=True):
            self.renderer.update_scene(data, camera=cam)
            images[name] = self.renderer.render().copy()
        return images

    def close(self) -> None:
        self.renderer.close()


class DepthPointCloud:
    """Depth images of some of the scene's depth cameras (`scene.DEPTH_CAMERAS`), back-projected to world
    points. Each camera costs one render (about 1 ms on a CPU under software GL for a dexterous hand)."""

    def __init__(
        self, model: mujoco.MjModel, n_points: int, cameras: list[str], width: int = 128, height: int = 96
    ) -> None:
        self.n_points = n_points
        # A render context reads these model settings when it is created; its offscreen buffer is sized to
        # the image, not to pictures (640x480). Together they cut the render from about 3 to 1 ms a frame.
        settings = [(model.vis.quality, name, value) for name, value in DEPTH_QUALITY.items()]
        settings += [(model.vis.global_, "offwidth", width), (model.vis.global_, "offheight", height)]
        saved = [getattr(obj, name) for obj, name, _ in settings]
        try:
            for obj, name, value in settings:
                setattr(obj, name, value)
            self.renderer = mujoco.Renderer(model, height=height, width=width)
        finally:
            for (obj, name, _), value in zip(settings, saved, strict=True):
                setattr(obj, name, value)
        self.renderer.enable_depth_rendering()
        # Depth sees geoms only: a vendor model's sites (frames, sensor volumes) and tendons are drawings,
        # not surfaces a sensor would see.
        self.option = mujoco.MjvOption()
        self.option.sitegroup[:] = 0
        self.option.flags[mujoco.mjtVisFlag.mjVIS_TENDON] = 0
        self.cameras = [model.camera(f"depth_{name}").id for name in cameras]
        self.focals = [0.5 * height / np.tan(np.deg2rad(model.cam_fovy[cam]) / 2) for cam in self.cameras]
        self.rays = None  # per camera, from its intrinsics (the same at every step)

    def pinhole_cameras(self, data: mujoco.MjData) -> list[PinholeCamera]:
        """The cameras as a rig's calibration gives them: OpenCV intrinsics (MuJoCo renders pixel centres at
        half-integers) and camera-to-world poses (MuJoCo cameras look along -z with y up)."""
        height, width = self.renderer.height, self.renderer.width
        cameras = []
        for cam, focal in zip(self.cameras, self.focals, strict=True):
            pose = np.eye(4)
            pose[:3, :3] = data.cam_xmat[cam].reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
            pose[:3, 3] = data.cam_xpos[cam]
            pose_rows = tuple(map(tuple, pose.tolist()))
            principal = (width / 2 - 0.5, height / 2 - 0.5)
            cameras.append(PinholeCamera(float(focal), float(focal), *principal, width, height, pose_rows))
        return cameras

    def depth_images(self, data: mujoco.MjData) -> list[np.ndarray]:
        """(H, W) depth in metres along each camera's optical axis."""
        images = []
        for cam in self.cameras:
            self.renderer.update_scene(data, camera=cam, scene_option=self.option)
            images.append(self.renderer.render().copy())
        return images

    def __call__(self, data: mujoco.MjData, rng: np.random.Generator) -> np.ndarray:
        cameras = self.pinhole_cameras(data)
        if self.rays is None:
            self.rays = [c.rays(self.renderer.height, self.renderer.width) for c in cameras]
        points = [
            back_project(depth, camera, rays, WORKSPACE_LOW[2])
            for depth, camera, rays in zip(self.depth_images(data), cameras, self.rays, strict=True)
        ]
        return crop_and_downsample(np.concatenate(points), self.n_points, rng)

    def close(self) -> None:
        self.renderer.close()


class GeometryPointCloud:
    """Points drawn once on every collision geom except the table, moved with the geoms each step."""

    POOL = 4  # points drawn per output point, so cropping and the voxel grid leave enough

    def __init__(self, model: mujoco.MjModel, n_points: int, exclude: set[int], seed: int = 0) -> None:
        self.n_points = n_points
        meshes = {}
        for g in range(model.ngeom):
            if g in exclude or not (model.geom_contype[g] or model.geom_conaffinity[g]):
                continue
            mesh = geom_mesh(model, g)
            if mesh is not None:
                meshes[g] = mesh
        areas = np.array([m.area for m in meshes.values()])
        counts = np.maximum(1, np.round(areas / areas.sum() * self.POOL * n_points)).astype(int)
        local, owner = [], []
        for (g, mesh), count in zip(meshes.items(), counts, strict=True):
            points, _ = trimesh.sample.sample_surface(mesh, int(count), seed=seed)
            local.append(points)
            owner.append(np.full(int(count), g))
        self.local = np.concatenate(local)
        self.geoms = np.concatenate(owner)

    def __call__(self, data: mujoco.MjData, rng: np.random.Generator) -> np.ndarray:
        rot = data.geom_xmat[self.geoms].reshape(-1, 3, 3)
        points = np.einsum("nij,nj->ni", rot, self.local) + data.geom_xpos[self.geoms]
        return crop_and_downsample(points, self.n_points, rng)

    def close(self) -> None:
        """Nothing to release (the same interface as the depth source)."""


class SceneViews:
    """What an env sees of its scene, each made on first use and closed together: the point cloud (the
    depth cameras', or sampled on the geometry without the table and floor) and pictures from the render
    camera with the scenery drawn."""

    def __init__(
        self, model: mujoco.MjModel, source: str, n_points: int, depth_cameras: list[str],
        render_size: tuple[int, int],
    ) -> None:  # fmt: skip
        self.model, self.source, self.n_points = model, source, n_points
        self.depth_cameras, self.render_size = depth_cameras, render_size
        self.sampler: DepthPointCloud | GeometryPointCloud | None = None
        self._renderer: mujoco.Renderer | None = None
        self._picture_option = mujoco.MjvOption()  # what pictures show: the default groups and the scenery
        self._picture_option.geomgroup[SCENERY_GROUP] = 1

    def point_cloud(self, data: mujoco.MjData, rng: np.random.Generator) -> np.ndarray:
        """(n_points * 3,) world-frame xyz, flattened."""
        if self.sampler is None:
            if self.source == "depth":
                self.sampler = DepthPointCloud(self.model, self.n_points, self.depth_cameras)
            else:
                exclude = {self.model.geom("table").id, self.model.geom("floor").id}
                exclude |= {g for g in range(self.model.ngeom) if self.model.geom_group[g] == HIDDEN_GROUP}
                self.sampler = GeometryPointCloud(self.model, self.n_points, exclude)
        return self.sampler(data, rng).reshape(-1)

    def picture(self, data: mujoco.MjData) -> np.ndarray:
        if self._renderer is None:
            self._renderer = mujoco.Renderer(
                self.model, height=self.render_size[0], width=self.render_size[1]
            )
            # Without a GPU (Mesa's software GL) shadows and reflections make a frame 6x slower (113 vs
            # 19 ms), and lerobot-eval renders every step of the episodes it films.
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self._renderer.update_scene(data, camera=RENDER_CAMERA[0], scene_option=self._picture_option)
        return self._renderer.render()

    def close(self) -> None:
        for resource in (self.sampler, self._renderer):
            if resource is not None:
                resource.close()
        self.sampler = self._renderer = None
