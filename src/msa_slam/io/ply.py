"""Binary PLY of a point cloud (the run's map): the format CloudCompare, MeshLab, Open3D and trimesh open."""

from __future__ import annotations

import os

import numpy as np

from msa_slam.io.atomic import atomic_path


def write_ply(path: str | os.PathLike, points: np.ndarray) -> None:
    """Write (P, 3) points as little-endian binary PLY with float x, y, z vertices, atomically."""
    xyz = np.ascontiguousarray(np.asarray(points)[:, :3], dtype="<f4")
    header = ("ply\nformat binary_little_endian 1.0\ncomment written by msa-slam\n"
              f"element vertex {len(xyz)}\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            handle.write(header.encode("ascii"))
            handle.write(xyz.tobytes())
