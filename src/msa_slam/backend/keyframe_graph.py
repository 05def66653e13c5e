"""What the batch and the iSAM2 pose graphs share: keys and initial poses, the prior, odometry and loop factors
with their noise, the loops' consistency bookkeeping, and the accounted bytes."""

from __future__ import annotations

from typing import Any, ClassVar

import gtsam
import numpy as np

from msa_slam.backend.graph_config import GraphConfig, sigma_pair
from msa_slam.backend.inliers import ConsistencyGraph, InlierSelection, LoopEdge
from msa_slam.backend.noise import PathCovariance, bounded_covariance
from msa_slam.errors import InputError
from msa_slam.types import validate_pose

# Accounted bytes: an estimate of the heap GTSAM and this class hold, calibrated against glibc's in-use
# bytes (mallinfo2) on pose graphs of 2,000 keyframes (a chain; loops every 20 and 50 keyframes) and checked
# on the online city tour (2 laps: estimate within 2 % of the measured heap). A factor keeps its measurement,
# keys and Gaussian noise model (~600 B) and a pointer in each graph that lists it; a value keeps a Pose3 in
# gtsam.Values and the odometry pose here. iSAM2 adds each factor's linearised Jacobian and, per Bayes-tree
# non-zero (treeNnz), the conditional's full block storage, the cached separator factor, the clique and the
# delta vectors: ~60 B, not the 8 B of the non-zero itself. Graphs with many long random loops have larger
# separators than the estimate assumes (up to ~45 % more heap than estimated; tests/test_memory_accounting.py).
FACTOR_BYTES = 640
VALUE_BYTES = 680
ISAM2_FACTOR_BYTES = 800
ISAM2_NNZ_BYTES = 60


def _sigmas(rotation: float, translation: float) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Diagonal.Sigmas(np.array([rotation] * 3 + [translation] * 3))


class KeyframeGraph:
    """Bookkeeping shared by both optimisers: keys, initial poses, factor construction, accounting.
    `mode` (the run's verification mode) resolves `loop_inliers` and the robust kernel "auto"."""

    SELECTS_INLIERS: ClassVar[bool] = False  # whether this optimiser can leave loops out before optimising

    def __init__(self, config: GraphConfig | None = None, mode: str = "oracle") -> None:
        self.config = config or GraphConfig()
        cfg = self.config
        self.selects_inliers = self.SELECTS_INLIERS and cfg.selects_inliers(mode)
        self.kernel = cfg.loop_kernel(mode, self.selects_inliers)
        self._prior = _sigmas(cfg.prior_rotation, cfg.prior_translation)
        self._odometry = _sigmas(cfg.odometry_rotation, cfg.odometry_translation)
        self._odometry_floor = np.diag(sigma_pair(cfg.odometry_floor_rotation, cfg.odometry_floor_translation) ** 2)
        self._loop = _sigmas(cfg.loop_rotation, cfg.loop_translation)
        self._kernel = {
            "huber": gtsam.noiseModel.mEstimator.Huber,
            "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
            "none": None,
        }[self.kernel]
        self._keys: list[int] = []
        self._position: dict[int, int] = {}  # key -> position in the keyframe sequence (consistency checks)
        self._initial: dict[int, np.ndarray] = {}
        self.num_factors = 0
        self.num_loops = 0
        self._all = gtsam.NonlinearFactorGraph()  # every factor in the order added
        self._loop_slots: list[int] = []  # where each loop factor is in _all
        self._path = PathCovariance()  # keyframes' accumulated odometry covariance (consistency checks)
        self._consistency = ConsistencyGraph(cfg.inlier_confidence)  # the loops' pairwise consistency
        self.inliers: InlierSelection | None = None  # the last selection (None: every loop used)

    @property
    def factors(self) -> gtsam.NonlinearFactorGraph:
        """Every factor the optimiser used, in the order added (exported as g2o): loops left out by the
        consistency check are not."""
        dropped = {self._loop_slots[i] for i in self.dropped_loops}
        if not dropped:
            return self._all
        graph = gtsam.NonlinearFactorGraph()
        for slot in range(self._all.size()):
            if slot not in dropped:
                graph.push_back(self._all.at(slot))
        return graph

    @property
    def dropped_loops(self) -> tuple[int, ...]:
        """Indices (in the order added) of the loops the last optimisation left out as inconsistent."""
        if self.inliers is None:
            return ()
        kept = set(self.inliers.kept)
        return tuple(i for i in range(self.num_loops) if i not in kept)

    def describe(self) -> dict[str, Any]:
        """How loops entered the graph (metrics.json `loop_closing`): the kernel, whether inliers were
        selected and, after a selection, what it kept."""
        out: dict[str, Any] = {
            "loop_kernel": self.kernel,
            "loop_inliers": "consistent" if self.selects_inliers else "all",
        }
        if self.inliers is not None:
            sel = self.inliers
            out["inlier_selection"] = {
                "loops": self.num_loops,
                "kept": len(sel.kept),
                "dropped": self.num_loops - len(sel.kept),
                "method": sel.method,
                "consistent_pairs": sel.consistent_pairs,
                "chi2_threshold": round(sel.threshold, 4),
                "confidence": self.config.inlier_confidence,
            }
        return out

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
        """Accounted heap of the graph: factors and values (see FACTOR_BYTES), and the accumulated odometry
        covariance the consistency check keeps per keyframe (when it runs)."""
        return self.num_factors * FACTOR_BYTES + len(self._keys) * VALUE_BYTES + self._path.nbytes

    def _odometry_noise(self, motion: np.ndarray) -> gtsam.noiseModel.Base:
        if self.config.odometry_noise == "fixed":
            return self._odometry
        return gtsam.noiseModel.Gaussian.Covariance(self.config.drift.edge_covariance(motion) + self._odometry_floor)

    def _track_path(self, key: int, pose: np.ndarray, motion: np.ndarray | None) -> None:
        """Accumulate the odometry covariance and keyframe positions the consistency check needs (only when it
        runs: other graphs keep nothing more than before)."""
        if self.selects_inliers:
            self._position[key] = len(self._keys)
            self._path.append(pose, None if motion is None else self.config.odometry_covariance(motion))

    def _loop_noise(self, covariance: np.ndarray | None) -> gtsam.noiseModel.Base:
        cfg = self.config
        noise = self._loop
        if cfg.loop_noise == "hessian" and covariance is not None:
            noise = gtsam.noiseModel.Gaussian.Covariance(
                bounded_covariance(
                    covariance,
                    sigma_pair(cfg.loop_min_rotation, cfg.loop_min_translation),
                    sigma_pair(cfg.loop_max_rotation, cfg.loop_max_translation),
                )
            )
        if self._kernel is None:
            return noise
        return gtsam.noiseModel.Robust.Create(self._kernel.Create(cfg.robust_threshold), noise)

    def _keyframe_factors(self, key: int, pose: np.ndarray) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or key < 0:
            raise InputError(f"keyframe key must be a non-negative integer, got {key!r}")
        key = int(key)
        if key in self._initial:
            raise InputError(f"keyframe {key} was already added to the pose graph")
        pose = validate_pose(pose, where=f"keyframe {key} pose")
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        motion = None
        if self._keys:
            prev = self._keys[-1]
            motion = np.linalg.inv(self._initial[prev]) @ pose
            graph.add(gtsam.BetweenFactorPose3(prev, key, gtsam.Pose3(motion), self._odometry_noise(motion)))
        else:
            graph.add(gtsam.PriorFactorPose3(key, gtsam.Pose3(pose), self._prior))
        values.insert(key, gtsam.Pose3(pose))
        self._track_path(key, pose, motion)
        self._keys.append(key)
        self._initial[key] = pose
        self.num_factors += 1
        self._all.push_back(graph)
        return graph, values

    def _loop_factor(
        self, target_key: int, source_key: int, T_target_source: np.ndarray, covariance: np.ndarray | None
    ) -> gtsam.NonlinearFactorGraph:
        for key in (target_key, source_key):
            if key not in self._initial:
                raise InputError(f"loop {target_key}->{source_key}: keyframe {key} is not in the pose graph")
        if target_key == source_key:
            raise InputError(f"loop {target_key}->{source_key}: a loop needs two different keyframes")
        measured = validate_pose(T_target_source, where=f"loop {target_key}->{source_key} transform")
        if covariance is not None:
            covariance = np.asarray(covariance, dtype=np.float64)
            if covariance.shape != (6, 6) or not np.isfinite(covariance).all():
                raise InputError(
                    f"loop {target_key}->{source_key}: covariance must be a finite 6x6 matrix, "
                    f"got shape {covariance.shape}"
                )
        graph = gtsam.NonlinearFactorGraph()
        graph.add(
            gtsam.BetweenFactorPose3(
                int(target_key), int(source_key), gtsam.Pose3(measured), self._loop_noise(covariance)
            )
        )
        if self.selects_inliers:
            self._consistency.add(
                LoopEdge(
                    self._position[int(target_key)],
                    self._position[int(source_key)],
                    measured,
                    self.config.loop_covariance(covariance),
                ),
                self._path,
            )
        self._loop_slots.append(self._all.size())
        self._all.push_back(graph)
        self.num_factors += 1
        self.num_loops += 1
        return graph

    def _poses(self, values: gtsam.Values) -> np.ndarray:
        if not self._keys:
            return np.zeros((0, 4, 4))
        return np.stack([values.atPose3(k).matrix() for k in self._keys])
