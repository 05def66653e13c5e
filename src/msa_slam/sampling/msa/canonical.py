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
    when C lies within that rounding of a threshold (a cluster boundary or a sign tie).
    """
    scale = max(abs(lam[0]), abs(lam[m - 1]), 1e-300)
    tol = CLUSTER_RTOL * scale
    slack = SOLVER_RTOL * scale
    fragile = False
    sep = np.inf  # smallest gap between clusters: eigenvectors are determined to eps * scale / sep
    start = 0
    for j in range(1, m + 1):
        if j < m:
            gap = lam[j] - lam[j - 1]
            fragile = fragile or abs(gap - tol) <= 2 * slack
            if gap <= tol:
                continue
            sep = min(sep, gap)
        if j - start > 1:
            _cluster_basis(lam, vec, m, start, j, work)
        start = j
    err = slack / sep if sep < np.inf else SOLVER_RTOL  # how far a solver's eigenvectors may be off
    for j in range(m):
        top = 0
        for i in range(m):
            if abs(vec[i, j]) > abs(vec[top, j]):
                top = i
        edge = abs(vec[top, j]) - SIGN_ATOL
        pivot = -1
        for i in range(m):
            size = abs(vec[i, j])
            if pivot < 0 and size >= edge:
                pivot = i
            if abs(size - edge) <= 2 * err + 1e-15 and vec[i, j] * vec[top, j] < 0:
                fragile = True  # this component could take or lose the tie on another machine
        if vec[pivot, j] < 0:
            for i in range(m):
                vec[i, j] = -vec[i, j]
    return np.inf if fragile else err


@njit(cache=True)
def _cluster_basis(lam: np.ndarray, vec: np.ndarray, m: int, start: int, stop: int,
                   work: np.ndarray) -> None:  # pragma: no cover
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
