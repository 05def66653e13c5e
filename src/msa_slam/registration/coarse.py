"""A coarse initial guess for registering two keyframe clouds without an odometry prior.

A descriptor gives the yaw between two views of a place (Scan Context's column shift) but not the offset: a
revisit in the next lane or from a keyframe a few metres along the road starts metres off, beyond what GICP's
coarse pass pulls in. So translations on a horizontal grid (OFFSETS_M in x and y, in the target frame) are
scored by the fraction of the source's coarse points with a target point within SCORE_RADIUS_M, the best
REFINED are each registered at the coarse scale, and the one with the most inliers is the guess the verifier
starts from.
"""

from __future__ import annotations

import numpy as np
import small_gicp

from msa_slam.registration.prepared import PreparedCloud
from msa_slam.registration.verify import VerifierConfig, nearest_within

OFFSETS_M = (-6.0, -3.0, 0.0, 3.0, 6.0)  # grid in x and y: 25 starts, 1.5 m from any offset within +-7.5 m
SCORE_RADIUS_M = 1.5  # half the grid step: every offset within the grid scores on some start
REFINED = 3  # best-scoring starts registered


def coarse_guess(
    target: PreparedCloud, source: PreparedCloud, rotation_guess: np.ndarray, config: VerifierConfig
) -> np.ndarray:
    """T_target_source to start the verifier from: `rotation_guess` (its rotation and translation) moved by
    the grid offset whose coarse registration has the most inliers. The clouds are prepared ones
    (Verifier.prepare): the verifier's coarse pass uses the same preprocessing."""
    voxel, max_dist = 2.0 * config.voxel_size, 3.0 * config.max_correspondence_distance
    (tgt, tree), (src, _) = target.at(voxel), source.at(voxel)
    if tgt.size() < config.num_neighbors or src.size() < config.num_neighbors:
        return rotation_guess  # the verifier reports the clouds as too sparse
    points = src.points()[:, :3]
    starts = []
    for dx in OFFSETS_M:
        for dy in OFFSETS_M:
            T = rotation_guess.copy()
            T[:2, 3] += (dx, dy)
            starts.append((_inliers(tree, points, T, SCORE_RADIUS_M), T))
    starts.sort(key=lambda s: -s[0])
    best, best_T = -1, rotation_guess
    for _, T in starts[:REFINED]:
        result = small_gicp.align(
            tgt,
            src,
            tree,
            T,
            registration_type="GICP",
            max_correspondence_distance=max_dist,
            num_threads=config.num_threads,
            max_iterations=config.max_iterations,
        )
        aligned = np.asarray(result.T_target_source, dtype=np.float64)
        count = _inliers(tree, points, aligned, config.max_correspondence_distance)
        if count > best:
            best, best_T = count, aligned
    return best_T


def _inliers(tree: small_gicp.KdTree, points: np.ndarray, T: np.ndarray, radius: float) -> int:
    """Source `points` with a target point within `radius` after moving them by T."""
    return int(nearest_within(tree, points, T, radius)[2].sum())
