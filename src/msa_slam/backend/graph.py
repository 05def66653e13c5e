"""GTSAM pose graphs over keyframes (Dellaert et al., GTSAM): batch Levenberg-Marquardt and iSAM2.

Keyframe poses enter as odometry poses (world-from-LiDAR, 4x4). Consecutive keyframes are joined by a
between factor whose measurement is the odometry motion between them; verified loops add between factors
T_target_source, optionally under a robust kernel (Huber or Cauchy) so a wrong loop cannot drag the whole
graph. Tangent-space order in GTSAM's Pose3 is (rotation, translation), so sigmas are given that way.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import gtsam
import numpy as np
from pydantic import Field

from msa_slam.config import StageConfig

from msa_slam.errors import InputError
from msa_slam.types import validate_pose

# Accounted bytes (an estimate of what GTSAM holds, used to compare samplers, not a heap measurement):
# a Pose3 factor keeps its measurement (12 doubles), two keys and a 6x6 square-root information matrix
# with its 6 sigmas; a value keeps one Pose3 and its key; iSAM2 adds a 6x6 conditional per variable.
FACTOR_BYTES = 12 * 8 + 2 * 8 + 36 * 8 + 6 * 8
VALUE_BYTES = 12 * 8 + 8
ISAM2_VARIABLE_BYTES = 2 * 36 * 8


class GraphConfig(StageConfig):
    """Standard deviations (radians, metres) of the prior, odometry and loop factors, the robust loop kernel
    and the batch optimiser's iterations; the run configuration's `graph` section."""

    SECTION: ClassVar[str] = "graph"

    prior_rotation: float = Field(1e-4, gt=0)
    prior_translation: float = Field(1e-4, gt=0)
    odometry_rotation: float = Field(0.01, gt=0)
    odometry_translation: float = Field(0.1, gt=0)
    loop_rotation: float = Field(0.01, gt=0)
    loop_translation: float = Field(0.1, gt=0)
    robust: Literal["none", "huber", "cauchy"] = "none"
    robust_threshold: float = Field(1.0, gt=0)
    max_iterations: int = Field(100, ge=1)  # Levenberg-Marquardt (batch)


def _sigmas(rotation: float, translation: float) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Diagonal.Sigmas(np.array([rotation] * 3 + [translation] * 3))


class _KeyframeGraph:
    """Bookkeeping shared by both optimisers: keys, initial poses, factor construction, accounting."""

    def __init__(self, config: GraphConfig | None = None) -> None:
        self.config = config or GraphConfig()
        self._prior = _sigmas(self.config.prior_rotation, self.config.prior_translation)
        self._odometry = _sigmas(self.config.odometry_rotation, self.config.odometry_translation)
        loop = _sigmas(self.config.loop_rotation, self.config.loop_translation)
        if self.config.robust == "huber":
            loop = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(self.config.robust_threshold), loop)
        elif self.config.robust == "cauchy":
            loop = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Cauchy.Create(self.config.robust_threshold), loop)
        self._loop = loop
        self._keys: list[int] = []
        self._initial: dict[int, np.ndarray] = {}
        self.num_factors = 0
        self.num_loops = 0

    @property
    def keys(self) -> list[int]:
        return list(self._keys)

    def __len__(self) -> int:
        return len(self._keys)

    def initial_poses(self) -> np.ndarray:
        """(N, 4, 4) odometry poses of the keyframes in insertion order."""
        return np.stack([self._initial[k] for k in self._keys]) if self._keys else np.zeros((0, 4, 4))

    @property
    def nbytes(self) -> int:
        """Accounted memory of the graph (factors and values; see FACTOR_BYTES)."""
        return self.num_factors * FACTOR_BYTES + len(self._keys) * VALUE_BYTES

    def _keyframe_factors(self, key: int, pose: np.ndarray) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or key < 0:
            raise InputError(f"keyframe key must be a non-negative integer, got {key!r}")
        key = int(key)
        if key in self._initial:
            raise InputError(f"keyframe {key} was already added to the pose graph")
        pose = validate_pose(pose, where=f"keyframe {key} pose")
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if self._keys:
            prev = self._keys[-1]
            motion = np.linalg.inv(self._initial[prev]) @ pose
            graph.add(gtsam.BetweenFactorPose3(prev, key, gtsam.Pose3(motion), self._odometry))
        else:
            graph.add(gtsam.PriorFactorPose3(key, gtsam.Pose3(pose), self._prior))
        values.insert(key, gtsam.Pose3(pose))
        self._keys.append(key)
        self._initial[key] = pose
        self.num_factors += 1
        return graph, values

    def _loop_factor(self, target_key: int, source_key: int,
                     T_target_source: np.ndarray) -> gtsam.NonlinearFactorGraph:
        for key in (target_key, source_key):
            if key not in self._initial:
                raise InputError(f"loop {target_key}->{source_key}: keyframe {key} is not in the pose graph")
        if target_key == source_key:
            raise InputError(f"loop {target_key}->{source_key}: a loop needs two different keyframes")
        measured = validate_pose(T_target_source, where=f"loop {target_key}->{source_key} transform")
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.BetweenFactorPose3(int(target_key), int(source_key), gtsam.Pose3(measured), self._loop))
        self.num_factors += 1
        self.num_loops += 1
        return graph

    def _poses(self, values: gtsam.Values) -> np.ndarray:
        if not self._keys:
            return np.zeros((0, 4, 4))
        return np.stack([values.atPose3(k).matrix() for k in self._keys])


class PoseGraph(_KeyframeGraph):
    """Batch pose graph: collect keyframes and loops, then optimise with Levenberg-Marquardt."""

    def __init__(self, config: GraphConfig | None = None) -> None:
        super().__init__(config)
        self.max_iterations = self.config.max_iterations
        self._graph = gtsam.NonlinearFactorGraph()  # prior and odometry factors, in keyframe order
        self._loops = gtsam.NonlinearFactorGraph()  # loop factors, in the order they were added
        self._values = gtsam.Values()

    def add_keyframe(self, key: int, pose: np.ndarray) -> None:
        """Add a keyframe at its odometry pose; joined to the previous keyframe by the odometry motion."""
        graph, values = self._keyframe_factors(key, pose)
        self._graph.push_back(graph)
        self._values.insert(values)

    def add_loop(self, target_key: int, source_key: int, T_target_source: np.ndarray) -> None:
        """Add a verified loop: the pose of `source_key` seen from `target_key`."""
        self._loops.push_back(self._loop_factor(target_key, source_key, T_target_source))

    def update(self, extra_iterations: int = 0) -> None:
        """Nothing to do while frames arrive: the batch graph is optimised once, by `optimize`."""

    def optimize(self) -> np.ndarray:
        """Optimised (N, 4, 4) keyframe poses in insertion order, starting from the odometry poses.

        Odometry factors come before loop factors whatever order they were added in, so streaming keyframes
        and loops as they are found gives the same optimisation as adding all keyframes first."""
        if not self._keys:
            raise InputError("pose graph has no keyframes to optimise")
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.max_iterations)
        graph = gtsam.NonlinearFactorGraph()
        graph.push_back(self._graph)
        graph.push_back(self._loops)
        result = gtsam.LevenbergMarquardtOptimizer(graph, self._values, params).optimize()
        return self._poses(result)


class IncrementalPoseGraph(_KeyframeGraph):
    """Online pose graph on iSAM2 (Kaess et al., IJRR 2012): same interface, factors enter as they arrive."""

    def __init__(self, config: GraphConfig | None = None, relinearize_threshold: float = 0.01,
                 final_iterations: int = 10) -> None:
        super().__init__(config)
        self.final_iterations = int(final_iterations)
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(relinearize_threshold)
        self._isam = gtsam.ISAM2(params)
        self._pending_graph = gtsam.NonlinearFactorGraph()
        self._pending_values = gtsam.Values()
        self._num_updated = 0

    def add_keyframe(self, key: int, pose: np.ndarray) -> None:
        graph, values = self._keyframe_factors(key, pose)
        self._pending_graph.push_back(graph)
        self._pending_values.insert(values)

    def add_loop(self, target_key: int, source_key: int, T_target_source: np.ndarray) -> None:
        self._pending_graph.push_back(self._loop_factor(target_key, source_key, T_target_source))

    def update(self, extra_iterations: int = 0) -> None:
        """Hand pending factors to iSAM2; extra iterations relinearise further (useful after a loop)."""
        self._isam.update(self._pending_graph, self._pending_values)
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
        """Factors and values as in PoseGraph, per-variable iSAM2 state, and the Bayes tree's
        conditional matrices as GTSAM counts them (treeNnz doubles), which grow with loop fill-in."""
        return (super().nbytes + len(self._keys) * ISAM2_VARIABLE_BYTES
                + (self._isam.treeNnz() * 8 if self._num_updated else 0))
