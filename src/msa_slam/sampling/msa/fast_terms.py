"""Fast mode's terms through the window's Gram matrix, on lanes: forming C and eq. (5), which both pi
definitions share (fast_reference.py, fast_canonical.py).

With A the candidate's gradient operator (numpy.gradient's tridiagonal stencil, J^T = A F) and G_S its
block of the window's Gram matrix G = F F^T: C = A G_S A^T and e_j^2 = (a_{j+1} - a_j)^T G_S (a_{j+1} - a_j)
with a_j = sqrt(lam_j) v_j. Candidates are stored lane-innermost (the last index), so that every loop
vectorises over them; one candidate is one lane.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from msa_slam.sampling.msa.canonical import SOLVER_RTOL
from msa_slam.sampling.msa.terms import C_CLIP, EIGENVALUE_FLOOR


@njit(cache=True, error_model="numpy")
def form_lanes(
    members: np.ndarray,
    m: int,
    count: int,
    dist: np.ndarray,
    gram: np.ndarray,
    g: np.ndarray,
    c: np.ndarray,
    h: np.ndarray,
    rows: np.ndarray,
    clipped: np.ndarray,
) -> None:  # pragma: no cover
    """The Gram blocks G_S (g) and C = A G_S A^T (c) of `count` candidates of m members (members[:, lane]),
    lane-innermost so that the loops vectorise over the lanes; h (like g) and rows (3 or more, m,
    lanes) are scratch, clipped (lanes) flags the lanes whose C was cleaned.

    A's three diagonals are rows 0-2 (row k uses columns k-1, k, k+1). A's rows sum to zero, so C has an
    exact null vector, which the solver's unshifted first sweep takes out first (eigen._ql_lanes). Two
    members at the same distance from the first divide by zero: IEEE division (error_model="numpy")
    gives the inf or nan numpy.gradient gives, and C is then cleaned and clipped as the reference does."""
    lower, diag, upper = rows[0], rows[1], rows[2]
    for i in range(m):
        for j in range(m):
            for lane in range(count):
                g[i, j, lane] = gram[members[i, lane], members[j, lane]]
    for lane in range(count):
        first = dist[0, members[1, lane]] - dist[0, members[0, lane]]
        last = dist[0, members[m - 1, lane]] - dist[0, members[m - 2, lane]]
        lower[0, lane], diag[0, lane], upper[0, lane] = 0.0, -1.0 / first, 1.0 / first
        lower[m - 1, lane], diag[m - 1, lane], upper[m - 1, lane] = -1.0 / last, 1.0 / last, 0.0
    for k in range(1, m - 1):
        for lane in range(count):
            dx1 = dist[0, members[k, lane]] - dist[0, members[k - 1, lane]]
            dx2 = dist[0, members[k + 1, lane]] - dist[0, members[k, lane]]
            lower[k, lane] = -dx2 / (dx1 * (dx1 + dx2))
            diag[k, lane] = (dx2 - dx1) / (dx1 * dx2)
            upper[k, lane] = dx1 / (dx2 * (dx1 + dx2))
    for k in range(m):  # h = A G
        for j in range(m):
            for lane in range(count):
                v = diag[k, lane] * g[k, j, lane]
                if k > 0:
                    v += lower[k, lane] * g[k - 1, j, lane]
                if k < m - 1:
                    v += upper[k, lane] * g[k + 1, j, lane]
                h[k, j, lane] = v
    for lane in range(count):
        clipped[lane] = 0.0
    for i in range(m):  # C = (A G) A^T
        for k in range(m):
            for lane in range(count):
                v = diag[k, lane] * h[i, k, lane]
                if k > 0:
                    v += lower[k, lane] * h[i, k - 1, lane]
                if k < m - 1:
                    v += upper[k, lane] * h[i, k + 1, lane]
                c[i, k, lane] = v
                clipped[lane] = clipped[lane] if np.isfinite(v) else 1.0
    for lane in range(count):
        if clipped[lane] != 0.0:  # the reference's guard for coincident distances
            for i in range(m):
                for k in range(m):
                    v = 0.0 if np.isnan(c[i, k, lane]) else c[i, k, lane]
                    c[i, k, lane] = min(max(v, -C_CLIP), C_CLIP)


@njit(cache=True)
def pi_of_eigenpairs(lam: np.ndarray, vec: np.ndarray, g: np.ndarray, m: int, err: float):  # pragma: no cover
    """(pi, lowest, highest) of one candidate from C's eigen-pairs (vec's columns) and its Gram block
    G_S, already on one lane (g: (m, m, 1)): pi_lanes on one lane."""
    lam_lanes, vec_lanes = np.empty((m, 1)), np.empty((m, m, 1))
    lam_lanes[:, 0] = lam
    vec_lanes[:, :, 0] = vec
    values = np.empty((3, 1))
    pi_lanes(lam_lanes, vec_lanes, g, m, np.int64(1), np.full(1, err), values, np.empty((4, m, 1)), np.empty((4, 1)))
    return values[0, 0], values[1, 0], values[2, 0]


@njit(cache=True)
def pi_lanes(
    lam: np.ndarray,
    vec: np.ndarray,
    g: np.ndarray,
    m: int,
    count: int,
    err: np.ndarray,
    values: np.ndarray,
    rows: np.ndarray,
    per_lane: np.ndarray,
) -> None:  # pragma: no cover
    """Eq. (5) on every lane, lane-innermost so that the loops vectorise over the lanes: lam[:, lane]
    C's eigenvalues ascending, vec[:, j, lane] the eigenvector of lam[j, lane], g[:, :, lane] the
    candidate's Gram block G_S (e_j^2 = d_j^T G_S d_j, d_j = a_{j+1} - a_j, a_j = sqrt(lam_j) v_j).
    values[:, lane] = (pi, lowest, highest): pi plus or minus a bound on how far another solver's
    rounding could move it, from err[lane], the eigenvectors' error as canonicalise returns it (0: no
    bound wanted; inf: C sits at a threshold of the canonical form, bound 1). rows (4, m, lanes) and
    per_lane (4, lanes) are scratch. Each lane's sums run in a fixed order (over k for G d_j, then
    over i), so its values do not depend on the other lanes or their number."""
    scale, diff, gdiff, e = rows[0], rows[1], rows[2], rows[3]
    lo, hi, total, trace = per_lane[0], per_lane[1], per_lane[2], per_lane[3]
    for j in range(m):
        for lane in range(count):
            scale[j, lane] = np.sqrt(max(lam[j, lane], 0.0) + EIGENVALUE_FLOOR)
    for j in range(m - 1):
        for k in range(m):
            for lane in range(count):
                diff[k, lane] = vec[k, j + 1, lane] * scale[j + 1, lane] - vec[k, j, lane] * scale[j, lane]
                gdiff[k, lane] = 0.0
        for k in range(m):
            for i in range(m):
                for lane in range(count):
                    gdiff[i, lane] += g[k, i, lane] * diff[k, lane]
        for lane in range(count):
            e[j, lane] = 0.0
        for i in range(m):
            for lane in range(count):
                e[j, lane] += diff[i, lane] * gdiff[i, lane]
        for lane in range(count):
            e[j, lane] = np.sqrt(max(e[j, lane], 0.0))
    for lane in range(count):
        lo[lane] = hi[lane] = e[0, lane]
        total[lane] = trace[lane] = 0.0
    for j in range(1, m - 1):
        for lane in range(count):
            lo[lane] = min(lo[lane], e[j, lane])
            hi[lane] = max(hi[lane], e[j, lane])
    for j in range(m - 1):
        for lane in range(count):
            total[lane] += (e[j, lane] - lo[lane]) / (hi[lane] - lo[lane] + EIGENVALUE_FLOOR)
    for i in range(m):
        for lane in range(count):
            trace[lane] += g[i, i, lane]
    for lane in range(count):  # |delta e_j| <= 2 |delta a|_G, |delta a| <= err sqrt(lam_max) + |delta sqrt(lam)|
        pi = total[lane] / (m - 1)
        bound = 0.0
        if err[lane] > 0.0:
            shift = (
                2.0
                * np.sqrt(trace[lane])
                * (
                    err[lane] * scale[m - 1, lane]
                    + np.sqrt(SOLVER_RTOL * lam[m - 1, lane] + EIGENVALUE_FLOOR)
                    - np.sqrt(EIGENVALUE_FLOOR)
                )
            )
            bound = min(3.0 * shift / (hi[lane] - lo[lane] + EIGENVALUE_FLOOR), 1.0)
        values[0, lane], values[1, lane], values[2, lane] = pi, max(pi - bound, 0.0), min(pi + bound, 1.0)
