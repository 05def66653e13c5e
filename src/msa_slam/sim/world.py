"""A simulated world: one triangle mesh around a trajectory, with Embree ray casting.

The ground follows the trajectory (sensor height below each pose, so slopes and bridges of real paths
are respected) with mild relief away from the road; street structure comes from `layout`.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from trimesh.ray.ray_pyembree import RayMeshIntersector

from msa_slam.sim.layout import STYLES, StreetLayout
from msa_slam.sim.shapes import MeshBuilder
from msa_slam.errors import InputError


class World:
    """A mesh with per-face reflectance; `cast` gives the first hit (triangle, ray index, distance)."""

    def __init__(self, mesh: trimesh.Trimesh, reflectance: np.ndarray) -> None:
        self.mesh = mesh
        self.reflectance = reflectance
        self.face_normals = np.asarray(mesh.face_normals)
        self._face_origins = np.asarray(mesh.triangles[:, 0, :])
        self._intersector = RayMeshIntersector(mesh)

    @property
    def triangles(self) -> int:
        return len(self.mesh.faces)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hits of unit `directions` (R, 3) from `origins` ((3,) or (R, 3)): the distance comes from the
        hit triangle's plane, cheaper than asking trimesh for hit locations."""
        origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), directions.shape)
        tri, ray = self._intersector.intersects_id(origins, directions, multiple_hits=False)
        normals = self.face_normals[tri]
        num = np.einsum("ij,ij->i", self._face_origins[tri] - origins[ray], normals)
        dist = num / np.einsum("ij,ij->i", directions[ray], normals)
        return tri, ray, dist


class GroundModel:
    """Ground height at (x, y): inverse-distance blend of points `sensor_height` below the poses, plus
    mild seeded relief that fades in away from the road."""

    def __init__(self, poses: np.ndarray, sensor_height: float, rng: np.random.Generator) -> None:
        below = poses[:, :3, 3] - sensor_height * poses[:, :3, 2]
        keep = np.concatenate([[True], np.linalg.norm(np.diff(below[:, :2], axis=0), axis=1) > 1e-3])
        self.anchors = below[keep]
        self.tree = cKDTree(self.anchors[:, :2])
        self.k = min(8, len(self.anchors))
        self.waves = rng.uniform([0.02, 0.0, 0.0], [0.08, 2 * np.pi, 2 * np.pi], size=(4, 3))
        self.amp = rng.uniform(0.05, 0.12, size=4)

    def __call__(self, xy: np.ndarray) -> np.ndarray | float:
        pts = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        dist, idx = self.tree.query(pts, k=self.k)
        dist, idx = dist.reshape(len(pts), -1), idx.reshape(len(pts), -1)
        w = 1.0 / (dist + 0.5) ** 2
        z = (w * self.anchors[idx, 2]).sum(1) / w.sum(1)
        k, theta, phase = self.waves[:, 0], self.waves[:, 1], self.waves[:, 2]
        proj = pts[:, :1] * np.cos(theta) + pts[:, 1:2] * np.sin(theta)
        relief = (self.amp * np.sin(2 * np.pi * k * proj + phase)).sum(1)
        z = z + relief * np.clip((dist[:, 0] - 4.0) / 10.0, 0.0, 1.0)
        return z if np.ndim(xy) > 1 else float(z[0])


def extend_path(xy: np.ndarray, length: float) -> np.ndarray:
    """`xy` continued straight for `length` metres before its start and after its end, so the first and
    last scans see a street around them too (as a real drive that began and ended elsewhere)."""
    def heading(a: np.ndarray) -> np.ndarray:
        far = a[np.argmax(np.linalg.norm(a - a[0], axis=1) > 5.0)] if len(a) > 1 else a[0]
        d = far - a[0]
        n = np.linalg.norm(d)
        return d / n if n > 1e-6 else np.array([1.0, 0.0])

    steps = np.arange(length, 0.0, -1.0)[:, None]
    before = xy[0] - steps * heading(xy)
    after = xy[-1] - steps[::-1] * heading(xy[::-1])
    return np.concatenate([before, xy, after])


def build_world(poses: np.ndarray, style: str = "city", seed: int = 0, sensor_height: float = 1.73) -> World:
    """The world around `poses` (N, 4, 4): same seed and poses give the same world, triangle for triangle."""
    if style not in STYLES:
        raise InputError(f"unknown world style {style!r}; choose one of {', '.join(STYLES)}")
    st = STYLES[style]
    rng = np.random.default_rng(seed)
    ground = GroundModel(poses, sensor_height, rng)
    xy = extend_path(poses[:, :2, 3], 80.0)
    layout = StreetLayout(xy, st, rng, ground)
    layout.build()
    builder = MeshBuilder()
    layout.emit(builder)
    lo = xy.min(0) - st.ground_radius
    n = np.ceil((xy.max(0) + st.ground_radius - lo) / st.ground_cell).astype(int)
    gy, gx = np.mgrid[0:n[1] + 1, 0:n[0] + 1]
    grid = np.column_stack([lo[0] + gx.ravel() * st.ground_cell, lo[1] + gy.ravel() * st.ground_cell])
    centres = grid.reshape(n[1] + 1, n[0] + 1, 2)[:-1, :-1] + st.ground_cell / 2
    near, _ = layout.clear.tree.query(centres.reshape(-1, 2), distance_upper_bound=st.ground_radius)
    keep = np.isfinite(near).reshape(n[1], n[0])
    builder.height_field(lo, st.ground_cell, ground(grid).reshape(n[1] + 1, n[0] + 1), keep, 0.25)
    mesh, reflectance = builder.build()
    return World(mesh, reflectance)
