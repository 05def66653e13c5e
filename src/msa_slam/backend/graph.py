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
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

import gtsam
import numpy as np
from pydantic import Field

from msa_slam.backend.inliers import ConsistencyGraph, InlierSelection, LoopEdge
from msa_slam.backend.noise import DriftModel, PathCovariance, bounded_covariance
from msa_slam.config import StageConfig
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


class GraphConfig(StageConfig):
    """Noise of the prior, odometry and loop factors (radians, metres), the robust loop kernel and the batch
    optimiser's iterations; the run configuration's `graph` section.

    Odometry: `drift_translation` (fraction of the distance) and `drift_rotation` (rad per metre) over
    `drift_reference_m`, plus a per-edge floor (`odometry_floor_*`, for edges that barely move); with
    `odometry_noise="fixed"` every edge has `odometry_rotation`/`odometry_translation` instead. Loops: the
    registration's covariance with each direction's sigma within [loop_min_*, loop_max_*]; with
    `loop_noise="fixed"` (or no covariance) `loop_rotation`/`loop_translation`. `loop_inliers`: "consistent"
    keeps the largest pairwise-consistent set of loops (chi-square quantile `inlier_confidence`, 6 dof), "all"
    uses every loop, "auto" is consistent in realistic mode and all in oracle mode.
    """

    SECTION: ClassVar[str] = "graph"

    prior_rotation: float = Field(1e-4, gt=0)
    prior_translation: float = Field(1e-4, gt=0)
    odometry_noise: Literal["drift", "fixed"] = "drift"
    drift_translation: float = Field(0.005, gt=0)
    drift_rotation: float = Field(math.radians(0.17) / 100, gt=0)
    drift_reference_m: float = Field(100.0, gt=0)
    odometry_floor_rotation: float = Field(1e-5, gt=0)
    odometry_floor_translation: float = Field(1e-4, gt=0)
    odometry_rotation: float = Field(0.01, gt=0)
    odometry_translation: float = Field(0.1, gt=0)
    loop_noise: Literal["hessian", "fixed"] = "hessian"
    loop_min_rotation: float = Field(math.radians(0.25), gt=0)
    loop_min_translation: float = Field(0.05, gt=0)
    loop_max_rotation: float = Field(math.radians(5.0), gt=0)
    loop_max_translation: float = Field(1.0, gt=0)
    loop_rotation: float = Field(0.01, gt=0)
    loop_translation: float = Field(0.1, gt=0)
    robust: Literal["auto", "none", "huber", "cauchy"] = "auto"
    robust_threshold: float = Field(1.0, gt=0)
    loop_inliers: Literal["auto", "consistent", "all"] = "auto"
    inlier_confidence: float = Field(0.999, gt=0, lt=1)
    max_iterations: int = Field(100, ge=1)  # Levenberg-Marquardt (batch)

    @property
    def drift(self) -> DriftModel:
        return DriftModel(self.drift_translation, self.drift_rotation, self.drift_reference_m)

    def selects_inliers(self, mode: str) -> bool:
        """Whether the graph keeps only the pairwise-consistent loops in `mode` ("auto": realistic)."""
        return self.loop_inliers == "consistent" or self.loop_inliers == "auto" and mode == "realistic"

    def loop_kernel(self, mode: str, selects_inliers: bool | None = None) -> str:
        """The robust kernel of loop factors in `mode` ("auto": none when the graph selects consistent loops
        (`selects_inliers`, default: what the graph does in `mode`) or in oracle mode, else Cauchy)."""
        if self.robust != "auto":
            return self.robust
        if selects_inliers is None:
            selects_inliers = self.selects_inliers(mode)
        return "cauchy" if mode == "realistic" and not selects_inliers else "none"

    def loop_covariance(self, covariance: np.ndarray | None) -> np.ndarray:
        """The 6x6 covariance a loop factor gets: the registration's, bounded, or the fixed one."""
        if self.loop_noise == "hessian" and covariance is not None:
            return bounded_covariance(covariance, _pair(self.loop_min_rotation, self.loop_min_translation),
                                      _pair(self.loop_max_rotation, self.loop_max_translation))
        return np.diag(_pair(self.loop_rotation, self.loop_translation) ** 2)

    def odometry_covariance(self, motion: np.ndarray) -> np.ndarray:
        """The 6x6 covariance of an odometry edge with relative motion `motion`."""
        if self.odometry_noise == "fixed":
            return np.diag(_pair(self.odometry_rotation, self.odometry_translation) ** 2)
        floor = _pair(self.odometry_floor_rotation, self.odometry_floor_translation) ** 2
        return self.drift.edge_covariance(motion) + np.diag(floor)


def _sigmas(rotation: float, translation: float) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Diagonal.Sigmas(np.array([rotation] * 3 + [translation] * 3))


def _pair(rotation: float, translation: float) -> np.ndarray:
    return np.repeat([rotation, translation], 3)


class _KeyframeGraph:
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
        self._odometry_floor = np.diag(_pair(cfg.odometry_floor_rotation, cfg.odometry_floor_translation) ** 2)
        self._loop = _sigmas(cfg.loop_rotation, cfg.loop_translation)
        self._kernel = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
                        "none": None}[self.kernel]
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
        out: dict[str, Any] = {"loop_kernel": self.kernel,
                               "loop_inliers": "consistent" if self.selects_inliers else "all"}
        if self.inliers is not None:
            sel = self.inliers
            out["inlier_selection"] = {"loops": self.num_loops, "kept": len(sel.kept),
                                       "dropped": self.num_loops - len(sel.kept), "method": sel.method,
                                       "consistent_pairs": sel.consistent_pairs,
                                       "chi2_threshold": round(sel.threshold, 4),
                                       "confidence": self.config.inlier_confidence}
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
            noise = gtsam.noiseModel.Gaussian.Covariance(bounded_covariance(
                covariance, _pair(cfg.loop_min_rotation, cfg.loop_min_translation),
                _pair(cfg.loop_max_rotation, cfg.loop_max_translation)))
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

    def _loop_factor(self, target_key: int, source_key: int, T_target_source: np.ndarray,
                     covariance: np.ndarray | None) -> gtsam.NonlinearFactorGraph:
        for key in (target_key, source_key):
            if key not in self._initial:
                raise InputError(f"loop {target_key}->{source_key}: keyframe {key} is not in the pose graph")
        if target_key == source_key:
            raise InputError(f"loop {target_key}->{source_key}: a loop needs two different keyframes")
        measured = validate_pose(T_target_source, where=f"loop {target_key}->{source_key} transform")
        if covariance is not None:
            covariance = np.asarray(covariance, dtype=np.float64)
            if covariance.shape != (6, 6) or not np.isfinite(covariance).all():
                raise InputError(f"loop {target_key}->{source_key}: covariance must be a finite 6x6 matrix, "
                                 f"got shape {covariance.shape}")
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.BetweenFactorPose3(int(target_key), int(source_key), gtsam.Pose3(measured),
                                           self._loop_noise(covariance)))
        if self.selects_inliers:
            self._consistency.add(LoopEdge(self._position[int(target_key)], self._position[int(source_key)],
                                           measured, self.config.loop_covariance(covariance)), self._path)
        self._loop_slots.append(self._all.size())
        self._all.push_back(graph)
        self.num_factors += 1
        self.num_loops += 1
        return graph

    def _poses(self, values: gtsam.Values) -> np.ndarray:
        if not self._keys:
            return np.zeros((0, 4, 4))
        return np.stack([values.atPose3(k).matrix() for k in self._keys])


class PoseGraph(_KeyframeGraph):
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

    def add_loop(self, target_key: int, source_key: int, T_target_source: np.ndarray,
                 covariance: np.ndarray | None = None) -> None:
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
        kept = range(self._loops.size())
        if self.selects_inliers and self.num_loops:
            self.inliers = self._consistency.select()
            kept = self.inliers.kept
        graph = gtsam.NonlinearFactorGraph()
        graph.push_back(self._graph)
        for i in kept:
            graph.push_back(self._loops.at(i))
        result = gtsam.LevenbergMarquardtOptimizer(graph, self._values, params).optimize()
        return self._poses(result)


class IncrementalPoseGraph(_KeyframeGraph):
    """Online pose graph on iSAM2 (Kaess et al., IJRR 2012): same interface, factors enter as they arrive.

    With `loop_inliers` selecting consistent loops (realistic mode), each update re-decides the maximum
    pairwise-consistent set of the loops so far (ConsistencyGraph: only the new loops' pairs are tested) and
    hands iSAM2 the difference: loops that joined the set are added, loops that left it are removed from the
    system, so the estimate at every step uses the loops a batch run would keep if the stream ended there."""

    SELECTS_INLIERS = True

    def __init__(self, config: GraphConfig | None = None, relinearize_threshold: float = 0.01,
                 final_iterations: int = 10, mode: str = "oracle") -> None:
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

    def add_loop(self, target_key: int, source_key: int, T_target_source: np.ndarray,
                 covariance: np.ndarray | None = None) -> None:
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
