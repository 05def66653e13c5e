"""The paper's baseline samplers, exactly as the reference implementation behaves.

All are online and the first frame is always a keyframe (docs/msa.md, "Baselines").
- all samples; constant distance d (>= d from the last keyframe);
- entropy (Zeng et al.): histogram entropy ratio against the last keyframe, or > max distance;
- spaciousness (as in DLO, Chen et al.): distance threshold from a smoothed mean point range.
Each also takes the standstill gate `min_motion` / `min_rotation` (sampling/base.py, off by default): the same
rule as MSA's, so that methods are compared on the same frames.
"""

from __future__ import annotations

import numpy as np

from msa_slam.sampling import checks
from msa_slam.sampling.base import Sampler

MAX_BINS = 100  # per axis: 10^6 histogram cells, 8 MB (1000 would ask numpy for 8 GB)


class _DistanceGated(Sampler):
    """Shared bookkeeping: the last keyframe's translation."""

    def __init__(self, min_motion: float = 0.0, min_rotation: float = 0.0) -> None:
        super().__init__(min_motion, min_rotation)
        self._last_t: np.ndarray | None = None

    def _distance_to_last(self, pose: np.ndarray) -> float:
        return float(np.linalg.norm(pose[:3, 3] - self._last_t))


class AllSamples(Sampler):
    """Every frame is a keyframe (the paper's upper bound on memory and loop candidates)."""

    name = "all"

    def __init__(self, min_motion: float = 0.0, min_rotation: float = 0.0) -> None:
        super().__init__(min_motion, min_rotation)

    def _push(self, index, pose, descriptor, points):
        return [index]


class ConstantDistance(_DistanceGated):
    """A keyframe every `distance` metres travelled from the last keyframe (>=)."""

    name = "constant"

    def __init__(self, distance: float = 1.0, min_motion: float = 0.0, min_rotation: float = 0.0) -> None:
        super().__init__(min_motion, min_rotation)
        self.distance = checks.finite_float(self.name, "distance", distance, 0.0)

    def _push(self, index, pose, descriptor, points):
        if self._last_t is None or self._distance_to_last(pose) >= self.distance:
            self._last_t = pose[:3, 3].copy()
            return [index]
        return []


def histogram_entropy(points: np.ndarray, bins: int = 10) -> float:
    """-0.5 * sum p log2 p over the non-empty cells of a `bins`^3 histogram of the cloud."""
    counts, _ = np.histogramdd(points, bins=bins)
    p = counts[counts > 0] / counts.sum()
    return float(-0.5 * np.sum(p * np.log2(p)))


class Entropy(_DistanceGated):
    """Keyframe when the cloud's entropy departs from the last keyframe's by > threshold (ratio)."""

    name = "entropy"
    needs_points = True

    def __init__(self, threshold: float = 0.05, max_distance: float = 5.0, bins: int = 10,
                 min_motion: float = 0.0, min_rotation: float = 0.0) -> None:
        super().__init__(min_motion, min_rotation)
        self.threshold = checks.finite_float(self.name, "threshold", threshold, 0.0)
        self.max_distance = checks.finite_float(self.name, "max_distance", max_distance, 0.0, exclusive=True)
        self.bins = checks.integer(self.name, "bins", bins, 1, MAX_BINS)
        self._last_entropy = 0.0

    def _push(self, index, pose, descriptor, points):
        entropy = histogram_entropy(points, self.bins)
        if self._last_t is None or self._entropy_changed(entropy) \
                or self._distance_to_last(pose) > self.max_distance:
            self._last_t = pose[:3, 3].copy()
            self._last_entropy = entropy
            return [index]
        return []

    def _entropy_changed(self, entropy: float) -> bool:
        if self._last_entropy == 0.0:  # ratio is inf (changed) or nan (0/0: unchanged), as numpy gives
            return entropy != 0.0
        return abs(1.0 - entropy / self._last_entropy) > self.threshold


def spaciousness_threshold(spaciousness: float) -> float:
    """DLO's distance threshold as a function of the smoothed spaciousness."""
    if spaciousness > 10.0:
        return 3.0
    if spaciousness > 5.0:
        return 2.0
    if spaciousness > 3.0:
        return 1.0
    return spaciousness


class Spaciousness(_DistanceGated):
    """Keyframe when the distance travelled exceeds a threshold adapted to the scene's openness."""

    name = "spaciousness"
    needs_points = True

    def __init__(self, smoothing: float = 0.85, min_motion: float = 0.0, min_rotation: float = 0.0) -> None:
        super().__init__(min_motion, min_rotation)
        self.smoothing = checks.finite_float(self.name, "smoothing", smoothing, 0.0, below=1.0)
        self.spaciousness: float | None = None

    def _push(self, index, pose, descriptor, points):
        mean_range = float(np.mean(np.linalg.norm(points, axis=1)))
        if self.spaciousness is None:
            self.spaciousness = mean_range
        else:
            self.spaciousness = self.smoothing * self.spaciousness + (1.0 - self.smoothing) * mean_range
        if self._last_t is None or self._distance_to_last(pose) > spaciousness_threshold(self.spaciousness):
            self._last_t = pose[:3, 3].copy()
            return [index]
        return []
