"""The paper's baseline samplers, exactly as the reference implementation behaves.

All are online and the first frame is always a keyframe (docs/msa.md, "Baselines").
- all samples; constant distance d (>= d from the last keyframe);
- entropy (Zeng et al.): histogram entropy ratio against the last keyframe, or > max distance;
- spaciousness (as in DLO, Chen et al.): distance threshold from a smoothed mean point range.
Each also takes the standstill gate `min_motion` / `min_rotation` (sampling/base.py, off by default): the same
rule as MSA's, so that methods are compared on the same frames.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import Field

from msa_slam.sampling.base import Sampler
from msa_slam.sampling.params import Integer, Real, SamplerParams

MAX_BINS = 100  # per axis: 10^6 histogram cells, 8 MB (1000 would ask numpy for 8 GB)


class AllParams(SamplerParams):
    """`all` takes the standstill gate only (the SLAM core leaves it ungated: every frame, by definition)."""

    NAME = "all"
    sampler: Literal["all"] = "all"


class ConstantParams(SamplerParams):
    """Constant distance's parameter and the standstill gate."""

    NAME = "constant"
    sampler: Literal["constant"] = "constant"
    distance: Real = Field(1.0, ge=0, description="metres travelled from the last keyframe to the next (>=)")


class EntropyParams(SamplerParams):
    """The entropy sampler's parameters and the standstill gate."""

    NAME = "entropy"
    sampler: Literal["entropy"] = "entropy"
    threshold: Real = Field(0.05, ge=0, description="relative change of the cloud's entropy that makes a keyframe")
    max_distance: Real = Field(5.0, gt=0, description="metres after which a frame is a keyframe whatever its entropy")
    bins: Integer = Field(10, ge=1, le=MAX_BINS, description="histogram cells per axis of the entropy")


class SpaciousnessParams(SamplerParams):
    """The spaciousness sampler's parameter and the standstill gate."""

    NAME = "spaciousness"
    sampler: Literal["spaciousness"] = "spaciousness"
    smoothing: Real = Field(0.85, ge=0, lt=1, description="weight of the past in the smoothed mean point range")


class _DistanceGated(Sampler):
    """Shared bookkeeping: the last keyframe's translation."""

    def __init__(self, params: SamplerParams | None = None, /, **given: Any) -> None:
        super().__init__(params, **given)
        self._last_t: np.ndarray | None = None

    def _distance_to_last(self, pose: np.ndarray) -> float:
        return float(np.linalg.norm(pose[:3, 3] - self._last_t))


class AllSamples(Sampler):
    """Every frame is a keyframe (the paper's upper bound on memory and loop candidates)."""

    name = "all"
    Params = AllParams

    def _push(self, index, pose, descriptor, points):
        return [index]


class ConstantDistance(_DistanceGated):
    """A keyframe every `distance` metres travelled from the last keyframe (>=)."""

    name = "constant"
    Params = ConstantParams
    params: ConstantParams

    def __init__(self, params: ConstantParams | None = None, /, **given: Any) -> None:
        super().__init__(params, **given)
        self.distance = self.params.distance

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
    Params = EntropyParams
    params: EntropyParams
    needs_points = True

    def __init__(self, params: EntropyParams | None = None, /, **given: Any) -> None:
        super().__init__(params, **given)
        self.threshold, self.max_distance, self.bins = self.params.threshold, self.params.max_distance, self.params.bins
        self._last_entropy = 0.0

    def _push(self, index, pose, descriptor, points):
        entropy = histogram_entropy(points, self.bins)
        if self._last_t is None or self._entropy_changed(entropy) or self._distance_to_last(pose) > self.max_distance:
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
    Params = SpaciousnessParams
    params: SpaciousnessParams
    needs_points = True

    def __init__(self, params: SpaciousnessParams | None = None, /, **given: Any) -> None:
        super().__init__(params, **given)
        self.smoothing = self.params.smoothing
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
