"""Fast mode: pi through the window's descriptor Gram matrix, compiled, one candidate after another.

With A the candidate's gradient operator (numpy.gradient's tridiagonal stencil, J^T = A F) and G_S its
block of the window's Gram matrix G = F F^T: C = A G_S A^T and e_j^2 = (a_{j+1} - a_j)^T G_S (a_{j+1} - a_j)
with a_j = sqrt(lam_j) v_j. A candidate then costs O(m^3) instead of O(m^2 M). Algebraically equal to
terms.information, numerically not bit-identical (pi is ill-conditioned; docs/msa.md). The same kernels
give exact mode the extremes of pi under rounding (exact.fast_path_extremes).

Candidates are spread over numba's threads (parallel loop); the threading layer is numba's own
`workqueue` unless NUMBA_THREADING_LAYER names another: it survives a fork, unlike GNU OpenMP's
(it is not meant for concurrent calls from several Python threads; the pipeline makes none).
numba's cache keys each compiled function on its own module's source file only, and the code cached
here includes eigen.py's and canonical.py's kernels: a change to their code must come with a change to
this file.
"""

from __future__ import annotations

import os

import numba
import numpy as np
from numba import get_num_threads, njit, prange

from msa_slam.sampling.msa.canonical import SOLVER_RTOL, canonicalise
from msa_slam.sampling.msa.decision import decide
from msa_slam.sampling.msa.eigen import lane_buffers, symmetric_eigh, symmetric_eigh_lanes
from msa_slam.sampling.msa.powerset import feasible_subsets
from msa_slam.sampling.msa.terms import C_CLIP, EIGENVALUE_FLOOR, ScoreWeights, WindowResult

if "NUMBA_THREADING_LAYER" not in os.environ:  # before the first parallel call; see the module docstring
    numba.config.THREADING_LAYER = "workqueue"

PROBES = 3  # rounding-level perturbations of each candidate's C for the ambiguity screen (decision.py)
PROBE_SCALE = 1e-13  # their relative size: ~450 ulp, beyond any reordering of a BLAS kernel's sums


VECTORS, MATRICES = 8, 5  # a candidate's scratch: 8 vectors and 5 matrices of its size (the last one row taller)


@njit(cache=True)
def scratch_size(width: int) -> int:  # pragma: no cover
    """Length of the flat scratch buffer information_gram needs for candidates of up to `width` members."""
    return VECTORS * width + MATRICES * width * width + width


@njit(cache=True)
def _vector(scratch: np.ndarray, slot: int, m: int) -> np.ndarray:  # pragma: no cover
    """Vector `slot` of a candidate of m members in the flat scratch buffer (contiguous)."""
    return scratch[slot * m:(slot + 1) * m]


@njit(cache=True)
def _matrix(scratch: np.ndarray, slot: int, m: int, rows: int = 0) -> np.ndarray:  # pragma: no cover
    """Matrix `slot` (m x m, or rows x m) of a candidate in the flat scratch buffer: C-contiguous, so
    that its rows vectorise (views into a wider 2-D buffer are strided and do not)."""
    start = VECTORS * m + slot * m * m
    return scratch[start:start + max(rows, m) * m].reshape((max(rows, m), m))


@njit(cache=True)
def pairwise(translations: np.ndarray, descriptors: np.ndarray):  # pragma: no cover
    """Distances and similarities for all pairs (terms.similarity's values up to rounding).

    descriptors is (n, rings, sectors); a 1-D descriptor is passed as (n, dim, 1).
    """
    n, rows, cols = descriptors.shape
    dist = np.zeros((n, n))
    sim = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            d = 0.0
            for k in range(3):
                d += (translations[i, k] - translations[j, k]) ** 2
            dist[i, j] = dist[j, i] = np.sqrt(d)
            total = 0.0
            for col in range(cols):
                sq = 0.0
                for row in range(rows):
                    sq += (descriptors[i, row, col] - descriptors[j, row, col]) ** 2
                total += 1.0 / (1.0 + np.sqrt(sq))
            sim[i, j] = sim[j, i] = total
    return dist, sim


@njit(cache=True, error_model="numpy")
def _form_information(members: np.ndarray, m: int, dist: np.ndarray, gram: np.ndarray,
                      scratch: np.ndarray) -> None:  # pragma: no cover
    """The candidate's Gram block G_S (matrix 0 of scratch) and C = A G_S A^T (matrix 2).

    A's three diagonals are `lower`, `diag`, `upper` (row k uses columns k-1, k, k+1). Two members at
    the same distance from the first divide by zero: IEEE division (error_model="numpy") gives the
    inf or nan numpy.gradient gives, and C is then cleaned and clipped as the reference does.
    """
    lower, diag, upper = _vector(scratch, 0, m), _vector(scratch, 1, m), _vector(scratch, 2, m)
    g, h = _matrix(scratch, 0, m), _matrix(scratch, 1, m)
    lower[0] = 0.0
    upper[m - 1] = 0.0
    first = dist[0, members[1]] - dist[0, members[0]]
    last = dist[0, members[m - 1]] - dist[0, members[m - 2]]
    diag[0], upper[0] = -1.0 / first, 1.0 / first
    lower[m - 1], diag[m - 1] = -1.0 / last, 1.0 / last
    for k in range(1, m - 1):
        dx1 = dist[0, members[k]] - dist[0, members[k - 1]]
        dx2 = dist[0, members[k + 1]] - dist[0, members[k]]
        lower[k] = -dx2 / (dx1 * (dx1 + dx2))
        diag[k] = (dx2 - dx1) / (dx1 * dx2)
        upper[k] = dx1 / (dx2 * (dx1 + dx2))
    for i in range(m):
        for j in range(m):
            g[i, j] = gram[members[i], members[j]]
    for k in range(m):  # h = A G
        for j in range(m):
            v = diag[k] * g[k, j]
            if k > 0:
                v += lower[k] * g[k - 1, j]
            if k < m - 1:
                v += upper[k] * g[k + 1, j]
            h[k, j] = v
    c = _matrix(scratch, 2, m)  # C = (A G) A^T
    finite = True
    for i in range(m):
        for k in range(m):
            v = diag[k] * h[i, k]
            if k > 0:
                v += lower[k] * h[i, k - 1]
            if k < m - 1:
                v += upper[k] * h[i, k + 1]
            c[i, k] = v
            finite = finite and np.isfinite(v)
    if not finite:  # the reference's guard for coincident distances
        for i in range(m):
            for k in range(m):
                v = 0.0 if np.isnan(c[i, k]) else c[i, k]
                c[i, k] = min(max(v, -C_CLIP), C_CLIP)


@njit(cache=True)
def _eigen_of_information(scratch: np.ndarray, m: int) -> None:  # pragma: no cover
    """Canonical pi's eigen-decomposition of C (matrix 2 of scratch) into lam (vector 6) and vec (matrix 3),
    one matrix alone: for the rare C whose reduction meets an exactly zero column (symmetric_eigh_lanes)."""
    vec = _matrix(scratch, 3, m)
    vec[:, :] = _matrix(scratch, 2, m)
    symmetric_eigh(vec, _vector(scratch, 6, m), _vector(scratch, 7, m), m)


@njit(cache=True)
def _canonical_batch(scratches: np.ndarray, count: int, m: int, v: np.ndarray, d: np.ndarray, e: np.ndarray,
                     work: np.ndarray, out: np.ndarray, index: np.ndarray) -> None:  # pragma: no cover
    """(pi, lowest, highest) of `count` candidates of m members whose C is formed in scratches[lane]
    (matrix 2), into out[:, index[lane]]: their C decomposed together (symmetric_eigh_lanes), each
    lane's eigen-pairs sorted ascending into its scratch, then the canonical form and eq. (5) one by
    one. A lane's values depend on its own candidate only (not on the others in the batch)."""
    for i in range(m):
        for j in range(m):
            for lane in range(count):
                v[i, j, lane] = scratches[lane, VECTORS * m + 2 * m * m + i * m + j]
    symmetric_eigh_lanes(v, d, e, m, count, work)
    order = np.empty(m, dtype=np.int64)
    for lane in range(count):
        scratch = scratches[lane]
        if work[0, lane] != 0.0:
            _eigen_of_information(scratch, m)
        else:
            for j in range(m):  # ascending order, ties kept in place (symmetric_eigh's insertion sort)
                order[j] = j
                k = j
                while k > 0 and d[order[k - 1], lane] > d[order[k], lane]:
                    order[k - 1], order[k] = order[k], order[k - 1]
                    k -= 1
            lam, vec = _vector(scratch, 6, m), _matrix(scratch, 3, m)
            for j in range(m):
                lam[j] = d[order[j], lane]
                for r in range(m):
                    vec[r, j] = v[order[j], r, lane]
        out[0, index[lane]], out[1, index[lane]], out[2, index[lane]] = _canonical_pi(scratch, m)


@njit(cache=True)
def _canonical_pi(scratch: np.ndarray, m: int):  # pragma: no cover
    """(pi, lowest, highest) from the eigen-pairs left in scratch by _eigen_of_information: canonical
    form, eq. (5), and pi plus or minus its bound under solver rounding."""
    lam, vec = _vector(scratch, 6, m), _matrix(scratch, 3, m)
    err = canonicalise(lam, vec, m, _matrix(scratch, 4, m, m + 1))
    pi, bound = _pi_of_eigenpairs(lam, vec, _matrix(scratch, 0, m), m, scratch, err)
    return pi, max(pi - bound, 0.0), min(pi + bound, 1.0)


@njit(cache=True)
def information_gram(members: np.ndarray, m: int, dist: np.ndarray, gram: np.ndarray,
                     scratch: np.ndarray, probes: int, canonical: bool):  # pragma: no cover
    """pi of one candidate through G: returns (pi, lowest, highest). Reference pi: the extremes over
    `probes` eigen-decompositions of C perturbed by PROBE_SCALE (and pi itself). Canonical pi: pi plus
    or minus its bound under solver rounding (canonical.py), no probes needed."""
    _form_information(members, m, dist, gram, scratch)
    c, g = _matrix(scratch, 2, m), _matrix(scratch, 0, m)
    if canonical:  # a batch of one: the values of the batched loop
        v, d, e, work = lane_buffers(m)
        out = np.empty((3, 1))
        _canonical_batch(scratch[:scratch_size(m)].reshape((1, scratch_size(m))), 1, m, v, d, e, work, out,
                         np.zeros(1, dtype=np.int64))
        return out[0, 0], out[1, 0], out[2, 0]
    pi = _pi_of_information(c, g, m, scratch)
    lowest, highest = pi, pi
    probe = np.empty((m, m))
    for p in range(probes):
        for i in range(m):
            for k in range(m):  # a fixed symmetric pattern in [-1, 1], different per probe
                probe[i, k] = c[i, k] * (1.0 + PROBE_SCALE * np.sin(12.9898 * (p + 1) + 78.233 * (i + k)
                                                                    + 37.719 * i * k))
        value = _pi_of_information(probe, g, m, scratch)
        lowest, highest = min(lowest, value), max(highest, value)
    return pi, lowest, highest


@njit(cache=True)
def _pi_of_information(c: np.ndarray, g: np.ndarray, m: int, scratch: np.ndarray):  # pragma: no cover
    """The reference's pi from the information matrix C (LAPACK's eigen-pairs, as they come)."""
    lam, vec = _vector(scratch, 6, m), _matrix(scratch, 3, m)
    values, vectors = np.linalg.eigh(c)
    lam[:] = values
    vec[:, :] = vectors
    return _pi_of_eigenpairs(lam, vec, g, m, scratch, 0.0)[0]


@njit(cache=True)
def _pi_of_eigenpairs(lam: np.ndarray, vec: np.ndarray, g: np.ndarray, m: int, scratch: np.ndarray,
                      err: float):  # pragma: no cover
    """pi (eq. 5) from C's eigen-pairs and the candidate's Gram block G_S (e_j^2 = d_j^T G_S d_j), and a
    bound on how far another solver's rounding could move it, given err, the eigenvectors' error from
    canonicalise (0: no bound wanted; inf: C sits at a threshold of the canonical form, bound 1).

    The e_j are computed together, each sum in the order of the one-at-a-time loop (over k for G d_j,
    then over i for d_j . G d_j), with the independent j innermost: the compiler vectorises across j
    without reassociating any sum, so the values are those of the loop per j."""
    scale, e = _vector(scratch, 3, m), _vector(scratch, 5, m)[:m - 1]
    diff, gdiff = _matrix(scratch, 1, m), _matrix(scratch, 4, m)
    for j in range(m):
        scale[j] = np.sqrt(max(lam[j], 0.0) + EIGENVALUE_FLOOR)
    for i in range(m):  # column j of diff: d_j = a_{j+1} - a_j
        for j in range(m - 1):
            diff[i, j] = vec[i, j + 1] * scale[j + 1] - vec[i, j] * scale[j]
    gdiff[:, :] = 0.0
    for k in range(m):  # G d_j (G symmetric: its rows are contiguous)
        for i in range(m):
            gki = g[k, i]
            for j in range(m - 1):
                gdiff[i, j] += gki * diff[k, j]
    e[:] = 0.0
    for i in range(m):
        for j in range(m - 1):
            e[j] += diff[i, j] * gdiff[i, j]
    for j in range(m - 1):
        e[j] = np.sqrt(max(e[j], 0.0))
    lo, hi = e.min(), e.max()
    total = 0.0
    for j in range(m - 1):
        total += (e[j] - lo) / (hi - lo + EIGENVALUE_FLOOR)
    bound = 0.0
    if err > 0.0:  # |delta e_j| <= 2 |delta a|_G, |delta a| <= err sqrt(lam_max) + |delta sqrt(lam)|
        trace = 0.0
        for i in range(m):
            trace += g[i, i]
        shift = 2.0 * np.sqrt(trace) * (err * scale[m - 1] + np.sqrt(SOLVER_RTOL * lam[m - 1] + EIGENVALUE_FLOOR)
                                        - np.sqrt(EIGENVALUE_FLOOR))
        bound = min(3.0 * shift / (hi - lo + EIGENVALUE_FLOOR), 1.0)
    return total / (m - 1), bound


PARALLEL_FROM = 1000  # candidates per window from which threads share them: below, the hand-off to a
# worker thread costs more than it saves (and on a loaded machine the worker may wait for a time slice)


@njit(cache=True)
def _information_block(masks: np.ndarray, dist: np.ndarray, gram: np.ndarray, probes: int, canonical: bool,
                       out: np.ndarray, first: int, step: int) -> None:  # pragma: no cover
    """information_rows for the chunks of candidates first, first + step, ... (their columns of out;
    a chunk is eigen.LANES consecutive candidates). Canonical pi takes them in batches of up to
    eigen.LANES of the same size, whose C are decomposed together (_canonical_batch: the same values
    as one at a time); candidates come ordered by size, so a chunk is one batch but where the size
    changes (dealing single candidates in turn left every block a small batch of each size, and a
    batch of a few lanes costs nearly what a full one does)."""
    width = dist.shape[0]
    v, d, e, work = lane_buffers(width)
    lanes = v.shape[2]
    scratches = np.empty((lanes, scratch_size(width)))
    members = np.empty(width, dtype=np.int64)
    index = np.empty(lanes, dtype=np.int64)
    batch, batch_m = 0, 0  # candidates whose C waits in scratches[:batch], and their size
    for chunk in range(first, (len(masks) + lanes - 1) // lanes, step):
        for i in range(chunk * lanes, min((chunk + 1) * lanes, len(masks))):
            m = 0
            for p in range(width):
                if masks[i] >> p & 1:
                    members[m] = p
                    m += 1
            if m <= 2:
                continue
            if not canonical:
                out[0, i], out[1, i], out[2, i] = information_gram(members, m, dist, gram, scratches[0], probes, False)
                continue
            if batch > 0 and m != batch_m:
                _canonical_batch(scratches, batch, batch_m, v, d, e, work, out, index)
                batch = 0
            _form_information(members, m, dist, gram, scratches[batch])
            index[batch] = i
            batch_m = m
            batch += 1
            if batch == lanes:
                _canonical_batch(scratches, batch, m, v, d, e, work, out, index)
                batch = 0
    if batch > 0:
        _canonical_batch(scratches, batch, batch_m, v, d, e, work, out, index)


@njit(cache=True, parallel=True)
def information_rows(masks: np.ndarray, dist: np.ndarray, gram: np.ndarray, probes: int,
                     canonical: bool = False, blocks: int = 16) -> np.ndarray:  # pragma: no cover
    """(3, candidates): pi of the candidates (bit masks, powerset.feasible_subsets), and its lowest and
    highest value under rounding. Chunks of eigen.LANES consecutive candidates are dealt to `blocks` in
    turn (candidates come ordered by size, so contiguous ranges left the thread with the last blocks most
    of the work), and the blocks are shared by numba's threads (pass a few per thread); each
    candidate's arithmetic is the same whatever the thread count."""
    out = np.zeros((3, len(masks)))
    blocks = max(min(len(masks), blocks), 1)
    for block in prange(blocks):
        _information_block(masks, dist, gram, probes, canonical, out, block, blocks)
    return out


@njit(cache=True)
def information_rows_serial(masks: np.ndarray, dist: np.ndarray, gram: np.ndarray, probes: int,
                            canonical: bool = False) -> np.ndarray:  # pragma: no cover
    """information_rows on the calling thread (windows of fewer than PARALLEL_FROM candidates)."""
    out = np.zeros((3, len(masks)))
    _information_block(masks, dist, gram, probes, canonical, out, 0, 1)
    return out


def gram(descriptors: np.ndarray) -> np.ndarray:
    """G = F F^T of the window's flattened descriptors."""
    flat = descriptors.reshape(len(descriptors), -1)
    return flat @ flat.T


def optimise_fast(translations: np.ndarray, descriptors: np.ndarray, dmin: float, dmax: float,
                  weights: ScoreWeights, pi_definition: str = "reference") -> WindowResult:
    """The window's choice with pi through the Gram matrix (and its ambiguity from the probes)."""
    n = len(translations)
    blocks = descriptors.reshape(n, -1, 1) if descriptors.ndim == 2 else descriptors
    dist, sim = pairwise(np.ascontiguousarray(translations), np.ascontiguousarray(blocks))
    masks, rho = feasible_subsets(dist, sim, dmin, dmax)
    if masks.size == 0:
        return WindowResult((0, n - 1), 1)
    pi = pi_low = pi_high = None
    if weights.use_pi:
        canonical = pi_definition == "canonical"
        if masks.size < PARALLEL_FROM:
            pi, pi_low, pi_high = information_rows_serial(masks, dist, gram(descriptors), PROBES, canonical)
        else:
            pi, pi_low, pi_high = information_rows(masks, dist, gram(descriptors), PROBES, canonical,
                                                   8 * get_num_threads())
    best, ambiguous, margin = decide(int(masks.size), rho if weights.use_rho else None, pi, pi_low, pi_high, weights)
    return WindowResult(mask_positions(int(masks[best])), int(masks.size), ambiguous, margin)


def mask_positions(mask: int) -> tuple[int, ...]:
    """The window positions of a candidate's bit mask, ascending."""
    return tuple(p for p in range(mask.bit_length()) if mask >> p & 1)
