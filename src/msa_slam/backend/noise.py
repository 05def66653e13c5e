"""Noise of the pose graph's factors: odometry edges from a per-metre drift model, loop edges from the
registration's Hessian within bounds.

Odometry drift is modelled as white noise injected along the driven path (a random walk on SE(3)):
`q` variance per metre, in the tangent order GTSAM uses (rotation, translation). The covariance of one
edge is that noise integrated along the edge's constant-twist motion and carried to its end frame,
Sigma = length * int_0^1 Ad(Exp(-u xi)) Q Ad(Exp(-u xi))^T du (4-point Gauss-Legendre), so chaining two
edges gives the covariance of the single edge that spans both: a sampler that keeps fewer keyframes gets
neither a stiffer nor a looser chain. The rates are calibrated so that the standard deviation over
`reference_m` equals the relative drift over that length: q = drift^2 * reference_m.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import gtsam
import numpy as np

from msa_slam.errors import InputError

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(4)
_NODES, _WEIGHTS = (_NODES + 1) / 2, _WEIGHTS / 2  # on [0, 1]


@cache
def chi2_quantile(confidence: float, dof: int) -> float:
    """The chi-square distribution's `confidence` quantile with `dof` degrees of freedom: 2 P^-1(dof / 2,
    confidence) (P the regularised lower incomplete gamma function), what scipy's chi2.ppf computes, to the bit,
    without scipy.stats: it takes about a second to import, on a run's critical path after its odometry."""
    from scipy.special import gammaincinv

    if not 0.0 < confidence < 1.0 or dof < 1:
        raise InputError(f"chi-square quantile: needs 0 < confidence < 1 and dof >= 1, got {confidence} and {dof}")
    return float(2 * gammaincinv(dof / 2, confidence))


@dataclass(frozen=True)
class DriftModel:
    """Odometry drift: `translation` (fraction of the distance), `rotation` (rad per metre), both the
    relative error expected over `reference_m` metres (KITTI's relative-error metric)."""

    translation: float
    rotation: float
    reference_m: float

    @property
    def rates(self) -> np.ndarray:
        """Variance per metre of the 6 tangent components (rotation, translation)."""
        return np.repeat([self.rotation**2 * self.reference_m, self.translation**2 * self.reference_m], 3)

    def edge_covariance(self, motion: np.ndarray) -> np.ndarray:
        """6x6 covariance of an odometry edge with relative motion `motion` (4x4), in its end frame."""
        xi = gtsam.Pose3.Logmap(gtsam.Pose3(motion))
        length = float(np.linalg.norm(xi[3:]))  # path length of the constant-twist motion
        q = np.diag(self.rates)
        cov = np.zeros((6, 6))
        for u, w in zip(_NODES, _WEIGHTS):
            ad = gtsam.Pose3.Expmap(-u * xi).AdjointMap()
            cov += w * ad @ q @ ad.T
        return length * cov


class PathCovariance:
    """Odometry covariance accumulated along a pose sequence, for any two of its poses.

    Each edge's covariance (right perturbation, in its end frame) is carried to the world frame (left
    perturbation: Ad(X_end) Sigma Ad(X_end)^T) and summed in a running prefix, so the drift accumulated
    between poses a < b is the difference of two prefixes, expressed in b's frame: O(1) per pair, exact for
    the linearised chain, and for a random walk (DriftModel) the same as integrating the noise along the
    path. It follows the path's shape: a heading error picked up early moves the later positions sideways
    or, over a hill, vertically, which a per-metre allowance on the straight-line distance does not see.
    """

    def __init__(self) -> None:
        self._poses: list[np.ndarray] = []
        self._world: list[np.ndarray] = []  # prefix sums of the world-frame edge covariances

    def __len__(self) -> int:
        return len(self._poses)

    @property
    def nbytes(self) -> int:
        """Bytes of the prefix sums (the poses are the caller's arrays, not copied)."""
        return sum(w.nbytes for w in self._world)

    def append(self, pose: np.ndarray, edge_covariance: np.ndarray | None = None) -> None:
        """The next pose of the sequence and the covariance of the edge that reached it (None: the first)."""
        if not self._poses:
            self._world.append(np.zeros((6, 6)))
        else:
            if edge_covariance is None:
                raise InputError(f"path covariance: pose {len(self._poses)} lacks the covariance of its edge")
            ad = gtsam.Pose3(pose).AdjointMap()
            self._world.append(self._world[-1] + ad @ edge_covariance @ ad.T)
        self._poses.append(np.asarray(pose, dtype=np.float64))  # no copy of a float64 pose

    def between(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Odometry T_a_b (4x4) and its 6x6 covariance (rotation, translation; right perturbation of
        T_a_b) from the edges between positions `a` and `b` of the sequence, in either order."""
        lo, hi = min(a, b), max(a, b)
        inv_hi = np.linalg.inv(self._poses[hi])
        ad = gtsam.Pose3(inv_hi).AdjointMap()
        cov = ad @ (self._world[hi] - self._world[lo]) @ ad.T
        T = np.linalg.inv(self._poses[lo]) @ self._poses[hi]
        if a > b:  # T_b_a = inv(T_a_b): the perturbation moves to the other end
            ad_t = gtsam.Pose3(T).AdjointMap()
            T, cov = np.linalg.inv(T), ad_t @ cov @ ad_t.T
        return T, 0.5 * (cov + cov.T)


def bounded_covariance(covariance: np.ndarray, min_sigmas: np.ndarray, max_sigmas: np.ndarray) -> np.ndarray:
    """`covariance` with every direction's standard deviation kept within [min_sigmas, max_sigmas], measured
    in units of the bounds (eigenvalues clipped in the normalised space), so no loop is trusted more
    than a registration can be nor counts for nothing; a singular covariance is allowed (capped)."""
    cov = 0.5 * (covariance + covariance.T)
    for sigmas, clip in ((min_sigmas, lambda w: np.maximum(w, 1.0)), (max_sigmas, lambda w: np.minimum(w, 1.0))):
        scale = np.asarray(sigmas, dtype=np.float64)
        w, v = np.linalg.eigh(cov / np.outer(scale, scale))
        cov = np.outer(scale, scale) * ((v * clip(w)) @ v.T)
    return 0.5 * (cov + cov.T)
