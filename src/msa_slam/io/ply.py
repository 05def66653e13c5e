"""Binary PLY of a point cloud (the run's map): the format CloudCompare, MeshLab, Open3D and trimesh open,
written by plyfile."""

from __future__ import annotations

import os

import numpy as np

from msa_slam.io.atomic import atomic_path

VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])


def write_ply(path: str | os.PathLike, points: np.ndarray) -> None:
    """Write (P, 3) points as little-endian binary PLY with float x, y, z vertices, atomically."""
    from plyfile import PlyData, PlyElement

    vertices = np.ascontiguousarray(np.asarray(points)[:, :3], dtype="<f4").view(VERTEX).ravel()
    ply = PlyData([PlyElement.describe(vertices, "vertex")], byte_order="<", comments=["written by msa-slam"])
    with atomic_path(path) as tmp:
        ply.write(os.fspath(tmp))
