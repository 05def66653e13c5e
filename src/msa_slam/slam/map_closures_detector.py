"""Loop candidates from MapClosures (Gupta et al., "Effectively Detecting Loop Closures using Point Cloud Density
Maps", ICRA 2024; PyPI `map_closures`): a bird's-eye density image of each keyframe's local map, ORB features
matched through a binary search tree, and a RANSAC 2-D alignment whose inlier count ranks the candidates.

The package keeps its own database: each query also enters it, under the keyframe's row (its order among the
keyframes). It never returns rows within 3 of the query (measured: rows 1-3 after row 0 get no candidate), a
much shorter gap than loop closing's own exclusion (min_frame_gap, min_travel_m, exclude_recent), which
LoopCloser still applies. Its alignment `pose` maps the OLDER map's points into the query's frame (measured
in tests/test_local_map_loops.py), so the loop's initial guess T_match_query is its inverse.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msa_slam.errors import InputError

INSTALL = "pip install --no-deps map_closures==2.2.0"
# inliers -> a similarity in [0, 1) for the PR curve (monotone: the ranking is MapClosures' own); 50 inliers,
# ten times the package's acceptance default of 5, read as 0.5
INLIER_SCALE = 50.0


@dataclass(frozen=True)
class MapClosureMatch:
    """A candidate: the older keyframe, its similarity (inliers mapped to [0, 1)) and the package's alignment
    as T_match_query."""

    keyframe_id: int
    similarity: float
    T_match_query: np.ndarray


class MapClosuresDetector:
    """Queries and grows a MapClosures database with one local map per keyframe, in keyframe order."""

    def __init__(self) -> None:
        try:
            from map_closures.config import MapClosuresConfig
            from map_closures.map_closures import MapClosures
        except ImportError as exc:
            raise InputError(f"loop_detector=map-closures needs the map_closures package: {INSTALL} ({exc})") from None
        self._closures = MapClosures(MapClosuresConfig())
        self._frames: list[int] = []  # keyframe frame index by MapClosures row

    def query(self, frame: int, local_map: np.ndarray, k: int) -> list[MapClosureMatch]:
        """The best `k` older keyframes for keyframe `frame` (best first), which then joins the database."""
        row = len(self._frames)
        self._frames.append(int(frame))
        cloud = np.ascontiguousarray(local_map[:, :3], dtype=np.float64)
        found = self._closures.get_top_k_closures(row, cloud, int(k))
        matches = [
            MapClosureMatch(
                self._frames[c.source_id],
                c.number_of_inliers / (c.number_of_inliers + INLIER_SCALE),
                np.linalg.inv(np.asarray(c.pose, dtype=np.float64)),
            )
            for c in found
            if c.source_id < row
        ]
        return sorted(matches, key=lambda m: -m.similarity)
