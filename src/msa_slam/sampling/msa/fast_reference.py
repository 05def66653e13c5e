"""Fast mode's reference pi: LAPACK's eigen-pairs as they come, and the spread of pi under rounding-level
perturbations of C (the probes), which the decision turns into ambiguous windows (decision.py).

The reference's keyframes depend on which eigenvectors LAPACK returns (signs, bases of repeated
eigenvalues), so this path calls LAPACK on one candidate at a time, not the lane solver of
canonical pi (fast_canonical.py).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from msa_slam.sampling.msa.fast_terms import form_lanes, pi_of_eigenpairs

PROBES = 3  # rounding-level perturbations of each candidate's C for the ambiguity screen (decision.py)
PROBE_SCALE = 1e-13  # their relative size: ~450 ulp, beyond any reordering of a BLAS kernel's sums


@njit(cache=True)
def reference_information(
    members: np.ndarray, m: int, dist: np.ndarray, gram: np.ndarray, probes: int
):  # pragma: no cover
    """The reference's pi of one candidate (members[:m]) through G: returns (pi, lowest, highest), the
    extremes over `probes` eigen-decompositions of C perturbed by PROBE_SCALE (and pi itself)."""
    one = np.empty((m, 1), dtype=np.int64)
    one[:, 0] = members[:m]
    g, c_lane = np.empty((m, m, 1)), np.empty((m, m, 1))
    form_lanes(one, m, np.int64(1), dist, gram, g, c_lane, np.empty((m, m, 1)), np.empty((3, m, 1)), np.empty(1))
    c = c_lane.reshape((m, m))
    pi = _pi_of_information(c, g, m)
    lowest, highest = pi, pi
    probe = np.empty((m, m))
    for p in range(probes):
        for i in range(m):
            for k in range(m):  # a fixed symmetric pattern in [-1, 1], different per probe
                probe[i, k] = c[i, k] * (
                    1.0 + PROBE_SCALE * np.sin(12.9898 * (p + 1) + 78.233 * (i + k) + 37.719 * i * k)
                )
        value = _pi_of_information(probe, g, m)
        lowest, highest = min(lowest, value), max(highest, value)
    return pi, lowest, highest


@njit(cache=True)
def _pi_of_information(c: np.ndarray, g: np.ndarray, m: int):  # pragma: no cover
    """The reference's pi from the information matrix C (LAPACK's eigen-pairs, as they come); g is the
    Gram block G_S on one lane, (m, m, 1)."""
    values, vectors = np.linalg.eigh(c)
    return pi_of_eigenpairs(values, vectors, g, m, 0.0)[0]
