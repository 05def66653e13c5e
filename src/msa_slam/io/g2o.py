"""The pose graph as a g2o file (g2o_viewer, GTSAM's readG2o, most SLAM back ends read it): keyframe
vertices at their optimised poses, odometry and loop edges with the graph's information matrices.

g2o has no robust kernels: edges carry the Gaussian information only; the first vertex is fixed (FIX),
standing in for the prior factor."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

Edge = tuple[int, int, np.ndarray]  # (from vertex, to vertex, pose of `to` in the frame of `from`)


def _pose_fields(pose: np.ndarray) -> str:
    q = Rotation.from_matrix(pose[:3, :3]).as_quat()  # x y z w, as g2o's SE3:QUAT expects
    return " ".join(f"{round(v, 9) + 0.0:.9f}" for v in (*pose[:3, 3], *q))  # no "-0.000000000"


def _information(rotation_sigma: float, translation_sigma: float) -> str:
    """Upper triangle of the 6x6 information matrix in g2o's order (translation, then rotation)."""
    diag = [1.0 / translation_sigma**2] * 3 + [1.0 / rotation_sigma**2] * 3
    info = np.diag(diag)
    return " ".join(f"{info[r, c]:.6g}" for r in range(6) for c in range(r, 6))


def format_g2o(keys: Sequence[int], poses: np.ndarray, odometry_edges: Sequence[Edge], loop_edges: Sequence[Edge],
               odometry_sigmas: tuple[float, float], loop_sigmas: tuple[float, float]) -> str:
    """g2o text: VERTEX_SE3:QUAT per key, FIX of the first, EDGE_SE3:QUAT per odometry then loop edge;
    sigmas are (rotation [rad], translation [m])."""
    lines = [f"VERTEX_SE3:QUAT {int(k)} {_pose_fields(p)}" for k, p in zip(keys, poses)]
    for edges, sigmas in ((odometry_edges, odometry_sigmas), (loop_edges, loop_sigmas)):
        info = _information(*sigmas)
        lines += [f"EDGE_SE3:QUAT {int(a)} {int(b)} {_pose_fields(t)} {info}" for a, b, t in edges]
    if len(keys):
        lines.append(f"FIX {int(keys[0])}")
    return "\n".join(lines) + "\n"

