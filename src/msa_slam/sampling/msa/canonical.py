"""Canonical eigen-pairs: pi as a function of C alone, not of the solver, its rounding or the CPU.

pi (terms.information) compares consecutive eigenvectors of C. An eigenvector is only defined up to
its sign, and inside a (near-)repeated eigenvalue only its eigenspace is defined; LAPACK fixes both
through rounding-level quantities, so the reference's pi changes with the solver and the machine.
`pi="canonical"` fixes them from the data (docs/msa.md):

- clusters: sorted eigenvalues closer than CLUSTER_RTOL * max|lam| to their neighbour form one
  cluster; each cluster's eigenvalues are replaced by their mean and its eigenvectors by the canonical
  basis of the eigenspace: the coordinate axes projected onto it and orthonormalised, the axis with
  the largest remaining projection first (ties to the lower index);
- signs: each eigenvector's largest-magnitude component is positive (components within SIGN_ATOL of
  the largest count as ties, and the lowest index wins).

Between its thresholds the result moves continuously with C (eigenvectors to within
eps * |C| / gap <= eps / CLUSTER_RTOL), so rounding changes pi continuously; `canonicalise` also
reports how close C lies to a threshold (decision.py widens pi there).
"""

from __future__ import annotations

import numpy as np
from numba import njit

CLUSTER_RTOL = 1e-6  # relative eigenvalue gap below which eigenvectors are not individually determined
SIGN_ATOL = 1e-6  # components of a unit eigenvector this close to the largest magnitude tie for the sign
SOLVER_RTOL = 1e-13  # |error| of any backward-stable eigensolver on C, relative to max|lam| (~450 ulp)


@njit(cache=True)
def canonicalise(lam: np.ndarray, vec: np.ndarray, m: int, work: np.ndarray) -> float:  # pragma: no cover
    """Canonical form of the eigen-pairs (lam ascending, vec's columns) of an m x m C, in place.

    work is (m + 1, m) scratch. Returns how far another backward-stable solver's canonical
    eigenvectors may lie from these (SOLVER_RTOL * max|lam| / smallest gap between clusters), or inf
    when C lies within that rounding of a threshold (a cluster boundary or a sign tie). One matrix
    through the lane functions (count 1), which the batched fast path runs on many at once.
    """
    lam_lanes = np.empty((m, 1))
    lam_lanes[:, 0] = lam
    err, fragile, clustered = np.empty(1), np.empty(1), np.empty(1)
    cluster_scan_lanes(lam_lanes, m, np.int64(1), err, fragile, clustered)
    if clustered[0] != 0.0:
        tol = CLUSTER_RTOL * max(abs(lam[0]), abs(lam[m - 1]), 1e-300)
        start = np.int64(0)
        for j in range(1, m + 1):
            if j < m and lam[j] - lam[j - 1] <= tol:
                continue
            if j - start > 1:
                _cluster_basis(lam, vec, m, start, j, work)
            start = j
    vec_lanes = np.empty((m, m, 1))
    vec_lanes[:, :, 0] = vec
    sign_convention_lanes(vec_lanes, m, np.int64(1), err, fragile)
    vec[:, :] = vec_lanes[:, :, 0]
    return np.inf if fragile[0] != 0.0 else err[0]


@njit(cache=True)
def cluster_scan_lanes(
    lam: np.ndarray, m: int, count: int, err: np.ndarray, fragile: np.ndarray, clustered: np.ndarray
) -> None:  # pragma: no cover
    """The clusters of each lane's eigenvalues lam[:, lane] (ascending), lane-innermost so that the
    loops vectorise over the lanes: clustered[lane] = 1 where one exists (its eigenvectors are then
    replaced by the eigenspace's basis, canonicalise), fragile[lane] = 1 where a gap lies within
    solver rounding of the cluster threshold, err[lane] = SOLVER_RTOL * max|lam| / the smallest gap
    between clusters (how far a backward-stable solver's eigenvectors may be off; SOLVER_RTOL alone
    when there is no such gap)."""
    sep = np.empty(count)
    for lane in range(count):
        sep[lane] = np.inf
        fragile[lane] = 0.0
        clustered[lane] = 0.0
    for j in range(1, m):
        for lane in range(count):
            scale = max(abs(lam[0, lane]), abs(lam[m - 1, lane]), 1e-300)
            tol = CLUSTER_RTOL * scale
            gap = lam[j, lane] - lam[j - 1, lane]
            fragile[lane] = 1.0 if abs(gap - tol) <= 2 * SOLVER_RTOL * scale else fragile[lane]
            clustered[lane] = 1.0 if gap <= tol else clustered[lane]
            sep[lane] = min(sep[lane], gap) if gap > tol else sep[lane]
    for lane in range(count):
        scale = max(abs(lam[0, lane]), abs(lam[m - 1, lane]), 1e-300)
        err[lane] = SOLVER_RTOL * scale / sep[lane] if sep[lane] < np.inf else SOLVER_RTOL


@njit(cache=True)
def sign_convention_lanes(
    vec: np.ndarray, m: int, count: int, err: np.ndarray, fragile: np.ndarray
) -> None:  # pragma: no cover
    """Each eigenvector vec[:, j, lane] turned so that its largest-magnitude component is positive
    (components within SIGN_ATOL of the largest tie, the lowest index wins), lane-innermost so that
    the loops vectorise over the lanes; fragile[lane] = 1 where a component lies within 2 err[lane]
    of taking or losing that tie with the other sign (another machine's rounding could flip it)."""
    size, top, pivot, found = np.empty(count), np.empty(count), np.empty(count), np.empty(count)
    for j in range(m):
        for lane in range(count):
            size[lane] = abs(vec[0, j, lane])
            top[lane] = vec[0, j, lane]
        for i in range(1, m):
            for lane in range(count):
                bigger = abs(vec[i, j, lane]) > size[lane]
                size[lane] = abs(vec[i, j, lane]) if bigger else size[lane]
                top[lane] = vec[i, j, lane] if bigger else top[lane]
        for lane in range(count):
            size[lane] -= SIGN_ATOL  # the edge: components at least this large tie for the sign
            found[lane] = 0.0
            pivot[lane] = 0.0
        for i in range(m):
            for lane in range(count):
                value = vec[i, j, lane]
                take = found[lane] == 0.0 and abs(value) >= size[lane]
                pivot[lane] = value if take else pivot[lane]
                found[lane] = 1.0 if take else found[lane]
                near = abs(abs(value) - size[lane]) <= 2 * err[lane] + 1e-15 and value * top[lane] < 0
                fragile[lane] = 1.0 if near else fragile[lane]
        for i in range(m):
            for lane in range(count):
                vec[i, j, lane] = -vec[i, j, lane] if pivot[lane] < 0 else vec[i, j, lane]


@njit(cache=True)
def _cluster_basis(
    lam: np.ndarray, vec: np.ndarray, m: int, start: int, stop: int, work: np.ndarray
) -> None:  # pragma: no cover
    """Columns start..stop-1 of vec span one eigenspace: replace them by its canonical basis and the
    eigenvalues by their mean (pivoted Gram-Schmidt of the projected coordinate axes)."""
    k = stop - start
    proj = work[:m, :m]  # P = V V^T: column i is axis i projected onto the eigenspace
    for i in range(m):
        for r in range(m):
            total = 0.0
            for c in range(start, stop):
                total += vec[i, c] * vec[r, c]
            proj[r, i] = total
    used = work[m, :m]
    used[:] = 0.0
    mean = 0.0
    for c in range(start, stop):
        mean += lam[c]
    mean /= k
    for c in range(start, stop):
        best, best_norm = -1, -1.0
        for i in range(m):
            if used[i] != 0.0:
                continue
            norm = 0.0
            for r in range(m):
                norm += proj[r, i] ** 2
            if norm > best_norm + SIGN_ATOL:  # near-ties go to the lower index
                best, best_norm = i, norm
        used[best] = 1.0
        inv = 1.0 / np.sqrt(best_norm)
        for r in range(m):
            vec[r, c] = proj[r, best] * inv
        for i in range(m):  # remove the new direction from the remaining projected axes
            if used[i] != 0.0:
                continue
            dot = 0.0
            for r in range(m):
                dot += vec[r, c] * proj[r, i]
            for r in range(m):
                proj[r, i] -= dot * vec[r, c]
        lam[c] = mean
