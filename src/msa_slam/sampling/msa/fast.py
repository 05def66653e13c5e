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

from msa_slam.sampling.msa.canonical import SOLVER_RTOL, canonicalise, cluster_scan_lanes, sign_convention_lanes
from msa_slam.sampling.msa.decision import decide
from msa_slam.sampling.msa.eigen import LANES, lane_buffers, symmetric_eigh, symmetric_eigh_lanes
from msa_slam.sampling.msa.powerset import feasible_subsets
from msa_slam.sampling.msa.terms import C_CLIP, EIGENVALUE_FLOOR, ScoreWeights, WindowResult

if "NUMBA_THREADING_LAYER" not in os.environ:  # before the first parallel call; see the module docstring
    numba.config.THREADING_LAYER = "workqueue"

PROBES = 3  # rounding-level perturbations of each candidate's C for the ambiguity screen (decision.py)
PROBE_SCALE = 1e-13  # their relative size: ~450 ulp, beyond any reordering of a BLAS kernel's sums


VECTORS, MATRICES = 2, 3  # one candidate's scratch (the one-matrix path): 2 vectors and 3 matrices of its size
# (the last one row taller): lam, e; C, eigenvectors, canonicalise's work


@njit(cache=True)
def scratch_size(width: int) -> int:  # pragma: no cover
    """Length of the flat scratch buffer of the one-matrix path for candidates of up to `width` members."""
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

    descriptors is (n, rings, sectors); a 1-D descriptor is passed as (n, dim, 1). With several sectors,
    their sums of squares build up side by side, the contiguous sector index innermost (each sum still
    adds its rings in order, so the values are those of one sector after another).
    """
    n, rows, cols = descriptors.shape
    dist = np.zeros((n, n))
    sim = np.zeros((n, n))
    sq = np.empty(cols)
    for i in range(n):
        for j in range(i + 1, n):
            d = 0.0
            for k in range(3):
                d += (translations[i, k] - translations[j, k]) ** 2
            dist[i, j] = dist[j, i] = np.sqrt(d)
            if cols == 1:  # a vector: one sum along it
                total = 0.0
                for row in range(rows):
                    total += (descriptors[i, row, 0] - descriptors[j, row, 0]) ** 2
                sq[0] = total
            else:
                sq[:] = 0.0
                for row in range(rows):
                    for col in range(cols):
                        sq[col] += (descriptors[i, row, col] - descriptors[j, row, col]) ** 2
            total = 0.0
            for col in range(cols):
                total += 1.0 / (1.0 + np.sqrt(sq[col]))
            sim[i, j] = sim[j, i] = total
    return dist, sim


@njit(cache=True, error_model="numpy")
def _form_lanes(members: np.ndarray, m: int, count: int, dist: np.ndarray, gram: np.ndarray, g: np.ndarray,
                c: np.ndarray, h: np.ndarray, rows: np.ndarray, clipped: np.ndarray) -> None:  # pragma: no cover
    """The Gram blocks G_S (g) and C = A G_S A^T (c) of `count` candidates of m members (members[:, lane]),
    lane-innermost so that the loops vectorise over the lanes; h (like g) and rows (3 or more, m,
    lanes) are scratch, clipped (lanes) flags the lanes whose C was cleaned.

    A's three diagonals are rows 0-2 (row k uses columns k-1, k, k+1). A's rows sum to zero, so C has an
    exact null vector, which the solver's unshifted first sweep takes out first (eigen._ql). Two members at the same
    distance from the first divide by zero: IEEE division (error_model="numpy") gives the inf or nan
    numpy.gradient gives, and C is then cleaned and clipped as the reference does."""
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
def _eigen_of_information(scratch: np.ndarray, m: int) -> None:  # pragma: no cover
    """Canonical pi's eigen-decomposition of C (matrix 0 of scratch) into lam (vector 0) and vec (matrix 1),
    one matrix alone: for the rare C whose reduction meets an exactly zero column (symmetric_eigh_lanes)."""
    vec = _matrix(scratch, 1, m)
    vec[:, :] = _matrix(scratch, 0, m)
    symmetric_eigh(vec, _vector(scratch, 0, m), _vector(scratch, 1, m), m)


@njit(cache=True)
def _batch_buffers(width: int):  # pragma: no cover
    """Scratch for _canonical_batch on up to eigen.LANES candidates of up to `width` members, lane-innermost:
    the solver's (eigen.lane_buffers), the sorted eigenvalues and eigenvectors, the Gram blocks, eq. (5)'s
    rows, per-lane values, the lanes' (pi, lowest, highest) and a copy of their C."""
    v, d, e, work = lane_buffers(width)
    lanes = v.shape[2]
    return (v, d, e, work, np.empty((width, lanes)), np.empty((width, width, lanes)), np.empty((width, width, lanes)),
            np.empty((4, width, lanes)), np.empty((8, lanes)), np.empty((3, lanes)), np.empty((width, width, lanes)))


@njit(cache=True)
def _sorted_lanes(d: np.ndarray, v: np.ndarray, lam: np.ndarray, vec: np.ndarray, m: int,
                  count: int) -> None:  # pragma: no cover
    """Every lane's eigen-pairs (d[i, lane], v[i, :, lane]) ascending into lam[:, lane] and vec's columns
    (lane by lane: a sorting network's exchanges on all lanes at once measured 2-4x slower). Ties keep
    their order (symmetric_eigh's insertion sort)."""
    order = np.empty(m, dtype=np.int64)
    for lane in range(count):
        for j in range(m):
            order[j] = j
            k = j
            while k > 0 and d[order[k - 1], lane] > d[order[k], lane]:
                order[k - 1], order[k] = order[k], order[k - 1]
                k -= 1
        for j in range(m):
            lam[j, lane] = d[order[j], lane]
            for r in range(m):
                vec[r, j, lane] = v[order[j], r, lane]


@njit(cache=True)
def _canonical_batch(members: np.ndarray, count: int, m: int, dist: np.ndarray, gram: np.ndarray, buffers,
                     scratch: np.ndarray, out: np.ndarray, index: np.ndarray) -> None:  # pragma: no cover
    """(pi, lowest, highest) of `count` candidates of m members (members[:, lane]) into
    out[:, index[lane]], every step on all lanes at once (`buffers` from _batch_buffers): G_S and C
    formed (_form_lanes), C decomposed (symmetric_eigh_lanes), the eigen-pairs sorted, the canonical
    form (canonical.py's lane functions) and eq. (5) (_pi_lanes). A lane the solver leaves out or
    whose eigenvalues form a cluster goes through the one-matrix path (_canonical_pi in `scratch`),
    with the same functions on one lane: a lane's values depend on its own candidate only."""
    v, d, e, work, lam, vec, g, rows, per_lane, values, kept = buffers
    _form_lanes(members, m, count, dist, gram, g, v, vec, rows, per_lane[0])
    for i in range(m):
        for j in range(m):
            for lane in range(count):
                kept[i, j, lane] = v[i, j, lane]
    symmetric_eigh_lanes(v, d, e, m, count, work)
    _sorted_lanes(d, v, lam, vec, m, count)
    err, fragile, clustered, bound = per_lane[0], per_lane[1], per_lane[2], per_lane[3]
    cluster_scan_lanes(lam, m, count, err, fragile, clustered)
    sign_convention_lanes(vec, m, count, err, fragile)
    for lane in range(count):
        bound[lane] = np.inf if fragile[lane] != 0.0 else err[lane]
    _pi_lanes(lam, vec, g, m, count, bound, values, rows, per_lane[4:])
    for lane in range(count):
        if work[0, lane] == 0.0 and clustered[lane] == 0.0:
            out[0, index[lane]], out[1, index[lane]], out[2, index[lane]] = values[0, lane], values[1, lane], \
                values[2, lane]
            continue
        gram_one, c_one = np.empty((m, m, 1)), _matrix(scratch, 0, m)
        for i in range(m):
            for j in range(m):
                gram_one[i, j, 0] = g[i, j, lane]
                c_one[i, j] = kept[i, j, lane]
        if work[0, lane] != 0.0:
            _eigen_of_information(scratch, m)
        else:
            # the sorted pairs, signs already turned: canonicalise gives the same bits (a sign change is
            # exact, and a cluster's basis depends only on its eigenspace)
            lam_one, vec_one = _vector(scratch, 0, m), _matrix(scratch, 1, m)
            for j in range(m):
                lam_one[j] = lam[j, lane]
                for r in range(m):
                    vec_one[r, j] = vec[r, j, lane]
        out[0, index[lane]], out[1, index[lane]], out[2, index[lane]] = _canonical_pi(scratch, gram_one, m)


@njit(cache=True)
def _canonical_pi(scratch: np.ndarray, g: np.ndarray, m: int):  # pragma: no cover
    """(pi, lowest, highest) from the eigen-pairs left in scratch (lam: vector 0, vec: matrix 1) and the Gram
    block g (m, m, 1), one candidate: canonical form, eq. (5), and pi plus or minus its bound under solver
    rounding."""
    lam, vec = _vector(scratch, 0, m), _matrix(scratch, 1, m)
    err = canonicalise(lam, vec, m, _matrix(scratch, 2, m, m + 1))
    return _pi_of_eigenpairs(lam, vec, g, m, err)


@njit(cache=True)
def information_gram(members: np.ndarray, m: int, dist: np.ndarray, gram: np.ndarray,
                     scratch: np.ndarray, probes: int, canonical: bool):  # pragma: no cover
    """pi of one candidate through G: returns (pi, lowest, highest). Reference pi: the extremes over
    `probes` eigen-decompositions of C perturbed by PROBE_SCALE (and pi itself). Canonical pi: pi plus
    or minus its bound under solver rounding (canonical.py), no probes needed."""
    one = np.empty((m, 1), dtype=np.int64)
    one[:, 0] = members[:m]
    if canonical:  # a batch of one: the values of the batched loop
        out = np.empty((3, 1))
        _canonical_batch(one, 1, m, dist, gram, _batch_buffers(m), scratch, out, np.zeros(1, dtype=np.int64))
        return out[0, 0], out[1, 0], out[2, 0]
    g, c = np.empty((m, m, 1)), np.empty((m, m, 1))
    _form_lanes(one, m, 1, dist, gram, g, c, np.empty((m, m, 1)), np.empty((3, m, 1)), np.empty(1))
    c = c.reshape((m, m))
    pi = _pi_of_information(c, g, m)
    lowest, highest = pi, pi
    probe = np.empty((m, m))
    for p in range(probes):
        for i in range(m):
            for k in range(m):  # a fixed symmetric pattern in [-1, 1], different per probe
                probe[i, k] = c[i, k] * (1.0 + PROBE_SCALE * np.sin(12.9898 * (p + 1) + 78.233 * (i + k)
                                                                    + 37.719 * i * k))
        value = _pi_of_information(probe, g, m)
        lowest, highest = min(lowest, value), max(highest, value)
    return pi, lowest, highest


@njit(cache=True)
def _pi_of_information(c: np.ndarray, g: np.ndarray, m: int):  # pragma: no cover
    """The reference's pi from the information matrix C (LAPACK's eigen-pairs, as they come); g is the
    Gram block G_S on one lane, (m, m, 1)."""
    values, vectors = np.linalg.eigh(c)
    return _pi_of_eigenpairs(values, vectors, g, m, 0.0)[0]


@njit(cache=True)
def _pi_of_eigenpairs(lam: np.ndarray, vec: np.ndarray, g: np.ndarray, m: int, err: float):  # pragma: no cover
    """(pi, lowest, highest) of one candidate from C's eigen-pairs (vec's columns) and its Gram block
    G_S, already on one lane (g: (m, m, 1)): _pi_lanes on one lane."""
    lam_lanes, vec_lanes = np.empty((m, 1)), np.empty((m, m, 1))
    lam_lanes[:, 0] = lam
    vec_lanes[:, :, 0] = vec
    values = np.empty((3, 1))
    _pi_lanes(lam_lanes, vec_lanes, g, m, 1, np.full(1, err), values, np.empty((4, m, 1)), np.empty((4, 1)))
    return values[0, 0], values[1, 0], values[2, 0]


@njit(cache=True)
def _pi_lanes(lam: np.ndarray, vec: np.ndarray, g: np.ndarray, m: int, count: int, err: np.ndarray,
              values: np.ndarray, rows: np.ndarray, per_lane: np.ndarray) -> None:  # pragma: no cover
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
            shift = 2.0 * np.sqrt(trace[lane]) * (err[lane] * scale[m - 1, lane]
                                                  + np.sqrt(SOLVER_RTOL * lam[m - 1, lane] + EIGENVALUE_FLOOR)
                                                  - np.sqrt(EIGENVALUE_FLOOR))
            bound = min(3.0 * shift / (hi[lane] - lo[lane] + EIGENVALUE_FLOOR), 1.0)
        values[0, lane], values[1, lane], values[2, lane] = pi, max(pi - bound, 0.0), min(pi + bound, 1.0)


PARALLEL_FROM = 1000  # candidates per window from which threads share them: below, the hand-off to a
# worker thread costs more than it saves (and on a loaded machine the worker may wait for a time slice)


@njit(cache=True)
def candidate_batches(masks: np.ndarray, lanes: int) -> np.ndarray:  # pragma: no cover
    """Batches of at most `lanes` consecutive candidates of one size (candidates come ordered by size):
    batch b is masks[starts[b]:starts[b + 1]]. Size-aligned, so that canonical pi decomposes each batch's C
    together (a chunk that straddles two sizes splits into two part-filled batches, and a batch of a few
    lanes costs nearly what a full one does)."""
    starts = np.empty(len(masks) + 1, dtype=np.int64)
    count, size, filled = 0, -1, 0
    for i in range(len(masks)):
        m = 0
        x = masks[i]
        while x:
            x &= x - 1
            m += 1
        if m != size or filled == lanes:
            starts[count] = i
            count += 1
            size, filled = m, 0
        filled += 1
    starts[count] = len(masks)
    return starts[:count + 1]


@njit(cache=True)
def _information_block(masks: np.ndarray, dist: np.ndarray, gram: np.ndarray, probes: int, canonical: bool,
                       out: np.ndarray, starts: np.ndarray, first: int, step: int) -> None:  # pragma: no cover
    """information_rows for the batches first, first + step, ... (candidate_batches; their columns of
    out). Canonical pi decomposes each batch's C together (_canonical_batch: the same values as one at a
    time); the reference pi takes its candidates one by one (information_gram)."""
    width = dist.shape[0]
    buffers = _batch_buffers(width)
    lanes = buffers[0].shape[2]
    scratch = np.empty(scratch_size(width))
    members = np.empty(width, dtype=np.int64)
    waiting = np.empty((width, lanes), dtype=np.int64)  # the members of the batch's candidates
    index = np.empty(lanes, dtype=np.int64)
    for b in range(first, len(starts) - 1, step):
        batch, batch_m = 0, 0
        for i in range(starts[b], starts[b + 1]):
            m = 0
            for p in range(width):
                if masks[i] >> p & 1:
                    members[m] = p
                    m += 1
            if m <= 2:
                break  # pi = 0 by definition; the whole batch has this size
            if not canonical:
                out[0, i], out[1, i], out[2, i] = information_gram(members, m, dist, gram, scratch, probes, False)
                continue
            waiting[:m, batch] = members[:m]
            index[batch] = i
            batch_m = m
            batch += 1
        if batch > 0:
            _canonical_batch(waiting, batch, batch_m, dist, gram, buffers, scratch, out, index)


@njit(cache=True, parallel=True)
def information_rows(masks: np.ndarray, dist: np.ndarray, gram: np.ndarray, probes: int,
                     canonical: bool = False, blocks: int = 2) -> np.ndarray:  # pragma: no cover
    """(3, candidates): pi of the candidates (bit masks, powerset.feasible_subsets), and its lowest and
    highest value under rounding. The size-aligned batches (candidate_batches) are dealt to `blocks` in
    turn, batch b to block b % blocks (candidates come ordered by size, so contiguous ranges left the
    thread with the last blocks most of the work), and the blocks are shared by numba's threads (pass
    the thread count: each then takes every other batch of each size); each candidate's arithmetic is
    the same whatever the thread count."""
    out = np.zeros((3, len(masks)))
    starts = candidate_batches(masks, LANES)
    blocks = max(min(len(starts) - 1, blocks), 1)
    for block in prange(blocks):
        _information_block(masks, dist, gram, probes, canonical, out, starts, block, blocks)
    return out


@njit(cache=True)
def information_rows_serial(masks: np.ndarray, dist: np.ndarray, gram: np.ndarray, probes: int,
                            canonical: bool = False) -> np.ndarray:  # pragma: no cover
    """information_rows on the calling thread (windows of fewer than PARALLEL_FROM candidates)."""
    out = np.zeros((3, len(masks)))
    _information_block(masks, dist, gram, probes, canonical, out, candidate_batches(masks, LANES), 0, 1)
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
                                                   get_num_threads())
    best, ambiguous, margin = decide(int(masks.size), rho if weights.use_rho else None, pi, pi_low, pi_high, weights)
    return WindowResult(mask_positions(int(masks[best])), int(masks.size), ambiguous, margin)


def mask_positions(mask: int) -> tuple[int, ...]:
    """The window positions of a candidate's bit mask, ascending."""
    return tuple(p for p in range(mask.bit_length()) if mask >> p & 1)
