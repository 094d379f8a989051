"""Link surfaces of a hand model as triangle meshes in each link's own frame, and sampling on them.

URDF geometry is read with yourdfpy (visual elements, falling back to collision), MJCF geometry from
the compiled MuJoCo model (visual-only geoms, falling back to all geoms). Sampling is area-weighted and
deterministic for a seed, so a hand's cloud is the same every time it is drawn.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import trimesh
import yourdfpy


def urdf_link_meshes(robot: yourdfpy.URDF, urdf_path: Path) -> dict[str, trimesh.Trimesh]:
    """Mesh of each URDF link that has geometry, in the link frame."""
    meshes = {}
    for name, link in robot.link_map.items():
        parts = [_urdf_geometry(element, urdf_path) for element in (link.visuals or link.collisions)]
        parts = [p for p in parts if p is not None and len(p.faces)]
        if parts:
            meshes[name] = trimesh.util.concatenate(parts)
    return meshes


def resolve_urdf_mesh(filename: str, urdf_path: Path) -> Path:
    resolved = Path(yourdfpy.filename_handler_magic(filename, dir=str(urdf_path.parent)))
    if not resolved.is_file():
        raise FileNotFoundError(f"{urdf_path}: mesh '{filename}' not found (looked for {resolved})")
    return resolved


def _urdf_geometry(element, urdf_path: Path) -> trimesh.Trimesh | None:
    geometry = element.geometry
    if geometry.box is not None:
        mesh = trimesh.creation.box(extents=geometry.box.size)
    elif geometry.cylinder is not None:
        mesh = trimesh.creation.cylinder(radius=geometry.cylinder.radius, height=geometry.cylinder.length)
    elif geometry.sphere is not None:
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=geometry.sphere.radius)
    elif geometry.mesh is not None:
        file = resolve_urdf_mesh(geometry.mesh.filename, urdf_path)
        mesh = trimesh.load(file, force="mesh").copy()
        if not len(mesh.faces) or not mesh.area > 0:
            raise ValueError(
                f"{urdf_path}: mesh '{geometry.mesh.filename}' ({file}) holds no surface: the file is "
                "corrupt or not a mesh trimesh reads"
            )
        if geometry.mesh.scale is not None:
            mesh.apply_scale(geometry.mesh.scale)
    else:
        return None
    if element.origin is not None:
        mesh.apply_transform(element.origin)
    return mesh


def mjcf_link_meshes(model: mujoco.MjModel) -> dict[str, trimesh.Trimesh]:
    """Mesh of each MuJoCo body that has geometry, in the body frame."""
    visual = (model.geom_contype == 0) & (model.geom_conaffinity == 0)
    meshes = {}
    for body in range(1, model.nbody):
        geoms = np.flatnonzero(model.geom_bodyid == body)
        chosen = geoms[visual[geoms]] if visual[geoms].any() else geoms
        parts = [p for p in (_mjcf_geometry(model, g) for g in chosen) if p is not None]
        if parts:
            meshes[model.body(body).name] = trimesh.util.concatenate(parts)
    return meshes


def geom_mesh(model: mujoco.MjModel, geom: int) -> trimesh.Trimesh | None:
    """A MuJoCo geom's surface in the geom's own frame (None for planes and other unbounded types)."""
    kind, size = model.geom_type[geom], model.geom_size[geom]
    g = mujoco.mjtGeom
    if kind == g.mjGEOM_BOX:
        return trimesh.creation.box(extents=2 * size)
    if kind == g.mjGEOM_SPHERE:
        return trimesh.creation.icosphere(subdivisions=3, radius=size[0])
    if kind == g.mjGEOM_CAPSULE:
        return trimesh.creation.capsule(radius=size[0], height=2 * size[1])
    if kind == g.mjGEOM_CYLINDER:
        return trimesh.creation.cylinder(radius=size[0], height=2 * size[1])
    if kind == g.mjGEOM_ELLIPSOID:
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
        mesh.apply_scale(size)
        return mesh
    if kind == g.mjGEOM_MESH:
        mesh_id = model.geom_dataid[geom]
        v0, nv = model.mesh_vertadr[mesh_id], model.mesh_vertnum[mesh_id]
        f0, nf = model.mesh_faceadr[mesh_id], model.mesh_facenum[mesh_id]
        return trimesh.Trimesh(
            model.mesh_vert[v0 : v0 + nv].copy(), model.mesh_face[f0 : f0 + nf].copy(), process=False
        )
    return None


def _mjcf_geometry(model: mujoco.MjModel, geom: int) -> trimesh.Trimesh | None:
    """The geom's surface in its body's frame."""
    mesh = geom_mesh(model, geom)
    if mesh is None:
        return None
    transform = np.eye(4)
    mujoco.mju_quat2Mat(transform[:3, :3].reshape(-1), model.geom_quat[geom])
    transform[:3, 3] = model.geom_pos[geom]
    mesh.apply_transform(transform)
    return mesh


def allocate_points(areas: np.ndarray, n_points: int, min_per_link: int) -> np.ndarray:
    """Points per link: `min_per_link` each, the rest proportional to surface area (largest remainder),
    so that small distal links, whose motion matters most, are never left empty."""
    n_links = len(areas)
    floor = min(min_per_link, n_points // n_links)
    share = (n_points - floor * n_links) * areas / areas.sum()
    counts = np.floor(share).astype(int)
    remainder = n_points - floor * n_links - counts.sum()
    counts[np.argsort(-(share - counts), kind="stable")[:remainder]] += 1
    return counts + floor


def sample_surface(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator) -> np.ndarray:
    """`count` points uniformly on the surface (faces chosen by area, uniform barycentric coordinates)."""
    triangles = mesh.triangles
    face = rng.choice(len(triangles), size=count, p=mesh.area_faces / mesh.area_faces.sum())
    a, b = rng.random((2, count, 1))
    flip = (a + b) > 1
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    t = triangles[face]
    return t[:, 0] + a * (t[:, 1] - t[:, 0]) + b * (t[:, 2] - t[:, 0])
