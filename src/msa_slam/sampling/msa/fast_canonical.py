"""Fast mode's canonical pi: up to eigen.LANES same-size candidates at a time, every step on all lanes at
once (C formed, decomposed by the lane solver, the eigen-pairs sorted, the canonical form, eq. (5)),
and pi's bound under solver rounding (canonical.py), so no probes are needed.

A lane whose eigenvalues form a cluster takes the one-matrix canonical form (canonicalise) in a flat
scratch buffer; a lane's values depend on its own candidate only, never on the other lanes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from msa_slam.sampling.msa.canonical import canonicalise, cluster_scan_lanes, sign_convention_lanes
from msa_slam.sampling.msa.eigen import lane_buffers, sort_lanes, symmetric_eigh_lanes
from msa_slam.sampling.msa.fast_terms import form_lanes, pi_lanes, pi_of_eigenpairs

VECTORS, MATRICES = 1, 2  # one candidate's scratch (the one-matrix canonical form): 1 vector and 2 matrices
# of its size (the last one row taller): lam; eigenvectors, canonicalise's work


@njit(cache=True)
def scratch_size(width: int) -> int:  # pragma: no cover
    """Length of the flat scratch buffer of the one-matrix path for candidates of up to `width` members."""
    return VECTORS * width + MATRICES * width * width + width


@njit(cache=True)
def _vector(scratch: np.ndarray, slot: int, m: int) -> np.ndarray:  # pragma: no cover
    """Vector `slot` of a candidate of m members in the flat scratch buffer (contiguous)."""
    return scratch[slot * m : (slot + 1) * m]


@njit(cache=True)
def _matrix(scratch: np.ndarray, slot: int, m: int, rows: int = 0) -> np.ndarray:  # pragma: no cover
    """Matrix `slot` (m x m, or rows x m) of a candidate in the flat scratch buffer: C-contiguous, so
    that its rows vectorise (views into a wider 2-D buffer are strided and do not)."""
    start = VECTORS * m + slot * m * m
    return scratch[start : start + max(rows, m) * m].reshape((max(rows, m), m))


@njit(cache=True)
def batch_buffers(width: int):  # pragma: no cover
    """Scratch for canonical_batch on up to eigen.LANES candidates of up to `width` members, lane-innermost:
    the solver's (eigen.lane_buffers), the sorted eigenvalues and eigenvectors, the Gram blocks, eq. (5)'s
    rows, per-lane values and the lanes' (pi, lowest, highest)."""
    v, d, e, work = lane_buffers(width)
    lanes = v.shape[2]
    return (
        v,
        d,
        e,
        work,
        np.empty((width, lanes)),
        np.empty((width, width, lanes)),
        np.empty((width, width, lanes)),
        np.empty((4, width, lanes)),
        np.empty((8, lanes)),
        np.empty((3, lanes)),
    )


@njit(cache=True)
def canonical_batch(
    members: np.ndarray,
    count: int,
    m: int,
    dist: np.ndarray,
    gram: np.ndarray,
    buffers,
    scratch: np.ndarray,
    out: np.ndarray,
    index: np.ndarray,
) -> None:  # pragma: no cover
    """(pi, lowest, highest) of `count` candidates of m members (members[:, lane]) into
    out[:, index[lane]], every step on all lanes at once (`buffers` from batch_buffers): G_S and C
    formed (fast_terms.form_lanes), C decomposed (eigen.symmetric_eigh_lanes), the eigen-pairs sorted,
    the canonical form (canonical.py's lane functions) and eq. (5) (fast_terms.pi_lanes). A lane whose
    eigenvalues form a cluster goes through the one-matrix canonical form (_canonical_pi in `scratch`),
    with the same functions on one lane: a lane's values depend on its own candidate only."""
    v, d, e, work, lam, vec, g, rows, per_lane, values = buffers
    form_lanes(members, m, count, dist, gram, g, v, vec, rows, per_lane[0])
    symmetric_eigh_lanes(v, d, e, m, count, work)
    sort_lanes(d, v, lam, vec, m, count)
    err, fragile, clustered, bound = per_lane[0], per_lane[1], per_lane[2], per_lane[3]
    cluster_scan_lanes(lam, m, count, err, fragile, clustered)
    sign_convention_lanes(vec, m, count, err, fragile)
    for lane in range(count):
        bound[lane] = np.inf if fragile[lane] != 0.0 else err[lane]
    pi_lanes(lam, vec, g, m, count, bound, values, rows, per_lane[4:])
    for lane in range(count):
        if clustered[lane] == 0.0:
            out[0, index[lane]], out[1, index[lane]], out[2, index[lane]] = (
                values[0, lane],
                values[1, lane],
                values[2, lane],
            )
            continue
        # the sorted pairs, signs already turned: canonicalise gives the same bits as on the solver's own
        # (a sign change is exact, and a cluster's basis depends only on its eigenspace)
        gram_one = np.empty((m, m, 1))
        lam_one, vec_one = _vector(scratch, 0, m), _matrix(scratch, 0, m)
        for i in range(m):
            lam_one[i] = lam[i, lane]
            for j in range(m):
                gram_one[i, j, 0] = g[i, j, lane]
                vec_one[i, j] = vec[i, j, lane]
        out[0, index[lane]], out[1, index[lane]], out[2, index[lane]] = _canonical_pi(scratch, gram_one, m)


@njit(cache=True)
def _canonical_pi(scratch: np.ndarray, g: np.ndarray, m: int):  # pragma: no cover
    """(pi, lowest, highest) from the eigen-pairs left in scratch (lam: vector 0, vec: matrix 0) and the Gram
    block g (m, m, 1), one candidate: canonical form, eq. (5), and pi plus or minus its bound under solver
    rounding."""
    lam, vec = _vector(scratch, 0, m), _matrix(scratch, 0, m)
    err = canonicalise(lam, vec, m, _matrix(scratch, 1, m, m + 1))
    return pi_of_eigenpairs(lam, vec, g, m, err)
