"""The pose graph's configuration (the run configuration's `graph` section): the noise of its prior, odometry
and loop factors, the robust loop kernel, which loops it keeps, the batch optimiser's iterations."""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from msa_slam.backend.noise import DriftModel, bounded_covariance
from msa_slam.config import StageConfig


def sigma_pair(rotation: float, translation: float) -> np.ndarray:
    """The six per-axis values of GTSAM's Pose3 tangent order (rotation, translation) from one of each."""
    return np.repeat([rotation, translation], 3)


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
            return bounded_covariance(
                covariance,
                sigma_pair(self.loop_min_rotation, self.loop_min_translation),
                sigma_pair(self.loop_max_rotation, self.loop_max_translation),
            )
        return np.diag(sigma_pair(self.loop_rotation, self.loop_translation) ** 2)

    def loop_covariance_bound(self) -> np.ndarray:
        """The largest covariance `loop_covariance` returns (in the Loewner order: every loop's is at most this):
        the registration's is bounded by the loop_max_* sigmas, the fixed one is itself."""
        if self.loop_noise == "hessian":
            return np.diag(sigma_pair(self.loop_max_rotation, self.loop_max_translation) ** 2)
        return self.loop_covariance(None)

    def odometry_covariance(self, motion: np.ndarray) -> np.ndarray:
        """The 6x6 covariance of an odometry edge with relative motion `motion`."""
        if self.odometry_noise == "fixed":
            return np.diag(sigma_pair(self.odometry_rotation, self.odometry_translation) ** 2)
        floor = sigma_pair(self.odometry_floor_rotation, self.odometry_floor_translation) ** 2
        return self.drift.edge_covariance(motion) + np.diag(floor)
