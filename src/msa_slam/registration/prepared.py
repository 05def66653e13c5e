"""A keyframe cloud as small_gicp registers it, prepared once per voxel size however many registrations use it.

small_gicp's preprocessing (voxel downsampling, neighbour covariances, normals, kd-tree) of a ~6,000-point keyframe
cloud costs about as much as a coarse registration, and the verified loop protocol used to repeat it six times a
candidate: its coarse search and the verifier's two passes each prepared both clouds, and a keyframe takes part in
several candidates (its own best matches, and as the match of later keyframes). The preprocessing is deterministic
(one thread), so sharing it changes no result.
"""

from __future__ import annotations

import numpy as np
import small_gicp

from msa_slam.types import as_points


class PreparedCloud:
    """`points` (P, 3) and, per voxel size, its preprocessed small_gicp cloud and kd-tree, made on first use."""

    def __init__(self, points: np.ndarray, num_neighbors: int, num_threads: int, where: str = "cloud") -> None:
        self.points = as_points(points, where)
        self.num_neighbors, self.num_threads = int(num_neighbors), int(num_threads)
        self._at: dict[float, tuple[small_gicp.PointCloud, small_gicp.KdTree]] = {}

    def at(self, voxel: float) -> tuple[small_gicp.PointCloud, small_gicp.KdTree]:
        """The cloud downsampled at `voxel` m with covariances and normals, and its kd-tree."""
        key = float(voxel)
        if key not in self._at:
            self._at[key] = small_gicp.preprocess_points(self.points, key, self.num_neighbors, self.num_threads)
        return self._at[key]
