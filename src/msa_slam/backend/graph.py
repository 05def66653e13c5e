"""GTSAM pose graphs over keyframes (Dellaert et al., GTSAM): batch Levenberg-Marquardt and iSAM2.

Keyframe poses enter as odometry poses (world-from-LiDAR, 4x4). Consecutive keyframes are joined by a
between factor whose measurement is the odometry motion between them and whose covariance grows with that
motion (backend/noise.py DriftModel, `odometry_noise="drift"`), so the chain has the same stiffness however
many keyframes a sampler keeps. Verified loops add between factors T_target_source weighted by the
registration's covariance kept within bounds (`loop_noise="hessian"`).

Which loops are used: with `loop_inliers="consistent"` ("auto": in realistic mode) the graph keeps the largest
set of pairwise consistent loops (backend/inliers.py: each pair's cycle through odometry tested against the
odometry covariance accumulated along its paths; the batch graph decides once when it optimises, iSAM2 at
every update, adding and removing loop factors as the set changes) and optimises them without a robust
kernel: a kernel on whitened residuals discounts the true loops that correct the most drift, which the
consistency test, unlike the kernel, tells from wrong ones. Otherwise every loop is used, optionally under a
robust kernel (`robust`: Huber or Cauchy; "auto": none when inliers are selected or in oracle mode, Cauchy
otherwise). Tangent-space
order in GTSAM's Pose3 is (rotation, translation), so sigmas are given that way.

Drift defaults: KISS-ICP (Vizzo et al., RA-L 2023) on the KITTI odometry training sequences, about 0.5 %
relative translation error and 0.17 deg per 100 m relative rotation error (KITTI's metric over 100-800 m
segments); `drift_reference_m=100` calibrates the random walk at the shortest KITTI segment.

Here the two optimisers; their configuration is graph_config.py's, what they share (factors, noise, the loops'
consistency bookkeeping, accounting) keyframe_graph.py's.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from msa_slam.backend.graph_config import GraphConfig
from msa_slam.backend.keyframe_graph import ISAM2_FACTOR_BYTES, ISAM2_NNZ_BYTES, KeyframeGraph
from msa_slam.errors import InputError


class PoseGraph(KeyframeGraph):
    """Batch pose graph: collect keyframes and loops, then optimise with Levenberg-Marquardt (after keeping
    the consistent loops when `loop_inliers` says so: all loops are known by then)."""

    SELECTS_INLIERS = True

    def __init__(self, config: GraphConfig | None = None, mode: str = "oracle") -> None:
        super().__init__(config, mode)
        self.max_iterations = self.config.max_iterations
        self._graph = gtsam.NonlinearFactorGraph()  # prior and odometry factors, in keyframe order
        self._loops = gtsam.NonlinearFactorGraph()  # loop factors, in the order they were added
        self._values = gtsam.Values()

    def add_keyframe(self, key: int, pose: np.ndarray) -> None:
        """Add a keyframe at its odometry pose; joined to the previous keyframe by the odometry motion."""
        graph, values = self._keyframe_factors(key, pose)
        self._graph.push_back(graph)
        self._values.insert(values)

    def add_loop(
        self, target_key: int, source_key: int, T_target_source: np.ndarray, covariance: np.ndarray | None = None
    ) -> None:
        """Add a verified loop: the pose of `source_key` seen from `target_key`, with the registration's
        6x6 covariance (rotation, translation) when it has one."""
        self._loops.push_back(self._loop_factor(target_key, source_key, T_target_source, covariance))

    def update(self, extra_iterations: int = 0) -> None:
        """Nothing to do while frames arrive: the batch graph is optimised once, by `optimize`."""

    def optimize(self) -> np.ndarray:
        """Optimised (N, 4, 4) keyframe poses in insertion order, starting from the odometry poses.

        Odometry factors come before loop factors whatever order they were added in, so streaming keyframes
        and loops as they are found gives the same optimisation as adding all keyframes first. With inlier
        selection on, only the largest pairwise-consistent set of loops enters (`inliers`)."""
        if not self._keys:
            raise InputError("pose graph has no keyframes to optimise")
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.max_iterations)
        kept: Sequence[int] = range(self._loops.size())
        if self.selects_inliers and self.num_loops:
            self.inliers = self._consistency.select()
            kept = self.inliers.kept
        graph = gtsam.NonlinearFactorGraph()
        graph.push_back(self._graph)
        for i in kept:
            graph.push_back(self._loops.at(i))
        result = gtsam.LevenbergMarquardtOptimizer(graph, self._values, params).optimize()
        return self._poses(result)


class IncrementalPoseGraph(KeyframeGraph):
    """Online pose graph on iSAM2 (Kaess et al., IJRR 2012): same interface, factors enter as they arrive.

    With `loop_inliers` selecting consistent loops (realistic mode), each update re-decides the maximum
    pairwise-consistent set of the loops so far (ConsistencyGraph: only the new loops' pairs are tested) and
    hands iSAM2 the difference: loops that joined the set are added, loops that left it are removed from the
    system, so the estimate at every step uses the loops a batch run would keep if the stream ended there."""

    SELECTS_INLIERS = True

    def __init__(
        self,
        config: GraphConfig | None = None,
        relinearize_threshold: float = 0.01,
        final_iterations: int = 10,
        mode: str = "oracle",
    ) -> None:
        super().__init__(config, mode)
        self.final_iterations = int(final_iterations)
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(relinearize_threshold)
        self._isam = gtsam.ISAM2(params)
        self._pending_graph = gtsam.NonlinearFactorGraph()
        self._pending_values = gtsam.Values()
        self._num_updated = 0
        self._loop_factors: list[gtsam.NonlinearFactorGraph] = []  # every loop's factor (inlier selection on)
        self._in_isam: dict[int, int] = {}  # loop index -> its factor's index in iSAM2
        self._selected_at = 0  # loops the current selection was made of

    def add_keyframe(self, key: int, pose: np.ndarray) -> None:
        graph, values = self._keyframe_factors(key, pose)
        self._pending_graph.push_back(graph)
        self._pending_values.insert(values)

    def add_loop(
        self, target_key: int, source_key: int, T_target_source: np.ndarray, covariance: np.ndarray | None = None
    ) -> None:
        factor = self._loop_factor(target_key, source_key, T_target_source, covariance)
        if self.selects_inliers:  # enters iSAM2 at the next update if the consistent set keeps it
            self._loop_factors.append(factor)
        else:
            self._pending_graph.push_back(factor)

    def _selection_changes(self) -> tuple[list[int], list[int]]:
        """Loops to add to iSAM2 and iSAM2 factor indices to remove, after re-selecting when loops arrived."""
        if not self.selects_inliers or self._selected_at == self.num_loops:
            return [], []
        self.inliers = self._consistency.select()
        self._selected_at = self.num_loops
        kept = set(self.inliers.kept)
        remove = [self._in_isam.pop(i) for i in sorted(self._in_isam) if i not in kept]
        return sorted(kept - set(self._in_isam)), remove

    def update(self, extra_iterations: int = 0) -> None:
        """Hand pending factors to iSAM2 (with the loops the consistency check now keeps or drops); extra
        iterations relinearise further (useful after a loop)."""
        add, remove = self._selection_changes()
        first_loop = self._pending_graph.size()
        for i in add:
            self._pending_graph.push_back(self._loop_factors[i])
        result = self._isam.update(self._pending_graph, self._pending_values, remove)
        indices = result.getNewFactorsIndices()
        for offset, i in enumerate(add):
            self._in_isam[i] = int(indices[first_loop + offset])
        self._pending_graph = gtsam.NonlinearFactorGraph()
        self._pending_values = gtsam.Values()
        self._num_updated = len(self._keys)
        for _ in range(extra_iterations):
            self._isam.update()

    def estimate(self) -> np.ndarray:
        """Current (N, 4, 4) estimate of the keyframes handed to iSAM2 so far (insertion order)."""
        if not self._num_updated:
            raise InputError("pose graph has no keyframes in iSAM2 yet (call update first)")
        values = self._isam.calculateEstimate()
        return np.stack([values.atPose3(k).matrix() for k in self._keys[: self._num_updated]])

    def optimize(self, extra_iterations: int | None = None) -> np.ndarray:
        """Update with everything pending (and `extra_iterations`, default `final_iterations`), then return
        the current estimate."""
        self.update(self.final_iterations if extra_iterations is None else extra_iterations)
        return self.estimate()

    @property
    def nbytes(self) -> int:
        """Factors and values as in PoseGraph, plus iSAM2's linearised factors and its Bayes tree, which
        grows with loop fill-in (see ISAM2_NNZ_BYTES)."""
        tree = self._isam.treeNnz() * ISAM2_NNZ_BYTES if self._num_updated else 0
        return super().nbytes + self.num_factors * ISAM2_FACTOR_BYTES + tree
