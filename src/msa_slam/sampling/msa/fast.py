"""Fast mode: pi through the window's descriptor Gram matrix, compiled: the candidate loop and the window's
choice. Per candidate, C = A G_S A^T (fast_terms.py) costs O(m^3) instead of O(m^2 M); the reference pi
(fast_reference.py) and the canonical one (fast_canonical.py) differ in how C is decomposed. Algebraically
equal to terms.information, numerically not bit-identical (pi is ill-conditioned; docs/msa.md). The same
kernels give exact mode the extremes of pi under rounding (exact.fast_path_extremes).

Candidates are spread over numba's threads (parallel loop); the threading layer is numba's own
`workqueue` unless NUMBA_THREADING_LAYER names another: it survives a fork, unlike GNU OpenMP's
(it is not meant for concurrent calls from several Python threads; the pipeline makes none).
numba's cache keys each compiled function on its own module's source file only, and the code cached
here and in fast_*.py includes the kernels of the modules they call (eigen.py, canonical.py, fast_terms.py
and the others): a change to a kernel's code must come with a change to every fast*.py file that calls it.
"""

from __future__ import annotations

import os

import numba
import numpy as np
from numba import get_num_threads, njit, prange

from msa_slam.sampling.msa.decision import decide
from msa_slam.sampling.msa.eigen import LANES
from msa_slam.sampling.msa.fast_canonical import batch_buffers, canonical_batch, scratch_size
from msa_slam.sampling.msa.fast_reference import PROBES, reference_information
from msa_slam.sampling.msa.powerset import feasible_subsets
from msa_slam.sampling.msa.terms import ScoreWeights, WindowResult

if "NUMBA_THREADING_LAYER" not in os.environ:  # before the first parallel call; see the module docstring
    numba.config.THREADING_LAYER = "workqueue"  # type: ignore[attr-defined]  # numba.config sets its options at import


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


@njit(cache=True)
def information_gram(
    members: np.ndarray, m: int, dist: np.ndarray, gram: np.ndarray, scratch: np.ndarray, probes: int, canonical: bool
):  # pragma: no cover
    """pi of one candidate through G: returns (pi, lowest, highest). Reference pi: the extremes over
    `probes` perturbed eigen-decompositions of C (fast_reference.py). Canonical pi: pi plus or minus its
    bound under solver rounding (fast_canonical.py), no probes needed; scratch: scratch_size(m) or more."""
    if not canonical:
        return reference_information(members, m, dist, gram, probes)
    one = np.empty((m, 1), dtype=np.int64)  # a batch of one: the values of the batched loop
    one[:, 0] = members[:m]
    out = np.empty((3, 1))
    canonical_batch(one, np.int64(1), m, dist, gram, batch_buffers(m), scratch, out, np.zeros(1, dtype=np.int64))
    return out[0, 0], out[1, 0], out[2, 0]


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
    return starts[: count + 1]


@njit(cache=True)
def _information_block(
    masks: np.ndarray,
    dist: np.ndarray,
    gram: np.ndarray,
    probes: int,
    canonical: bool,
    out: np.ndarray,
    starts: np.ndarray,
    first: int,
    step: int,
) -> None:  # pragma: no cover
    """information_rows for the batches first, first + step, ... (candidate_batches; their columns of
    out). Canonical pi decomposes each batch's C together (fast_canonical.canonical_batch: the same values
    as one at a time); the reference pi takes its candidates one by one (information_gram)."""
    width = dist.shape[0]
    buffers = batch_buffers(width)
    lanes = buffers[0].shape[2]
    scratch = np.empty(scratch_size(width))
    members = np.empty(width, dtype=np.int64)
    waiting = np.empty((width, lanes), dtype=np.int64)  # the members of the batch's candidates
    index = np.empty(lanes, dtype=np.int64)
    # Integers passed on to other kernels are int64, never literals: numba compiles a kernel once per type
    # it is called with, and a literal 0 or 1 is a type of its own (cold, canonical_batch and everything it
    # calls compiled five times, twice the CPU of a fresh checkout's first MSA run)
    for b in range(first, len(starts) - 1, step):
        batch, batch_m = np.int64(0), np.int64(0)
        for i in range(starts[b], starts[b + 1]):
            m = np.int64(0)
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
            canonical_batch(waiting, batch, batch_m, dist, gram, buffers, scratch, out, index)


@njit(cache=True, parallel=True)
def information_rows(
    masks: np.ndarray, dist: np.ndarray, gram: np.ndarray, probes: int, canonical: bool = False, blocks: int = 2
) -> np.ndarray:  # pragma: no cover
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
        _information_block(masks, dist, gram, probes, canonical, out, starts, np.int64(block), blocks)
    return out


@njit(cache=True)
def information_rows_serial(
    masks: np.ndarray, dist: np.ndarray, gram: np.ndarray, probes: int, canonical: bool = False
) -> np.ndarray:  # pragma: no cover
    """information_rows on the calling thread (windows of fewer than PARALLEL_FROM candidates)."""
    out = np.zeros((3, len(masks)))
    _information_block(
        masks, dist, gram, probes, canonical, out, candidate_batches(masks, LANES), np.int64(0), np.int64(1)
    )
    return out


def gram(descriptors: np.ndarray) -> np.ndarray:
    """G = F F^T of the window's flattened descriptors."""
    flat = descriptors.reshape(len(descriptors), -1)
    return flat @ flat.T


def optimise_fast(
    translations: np.ndarray,
    descriptors: np.ndarray,
    dmin: float,
    dmax: float,
    weights: ScoreWeights,
    pi_definition: str = "reference",
) -> WindowResult:
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
            pi, pi_low, pi_high = information_rows(masks, dist, gram(descriptors), PROBES, canonical, get_num_threads())
    best, ambiguous, margin = decide(int(masks.size), rho if weights.use_rho else None, pi, pi_low, pi_high, weights)
    return WindowResult(mask_positions(int(masks[best])), int(masks.size), ambiguous, margin)


def mask_positions(mask: int) -> tuple[int, ...]:
    """The window positions of a candidate's bit mask, ascending."""
    return tuple(p for p in range(mask.bit_length()) if mask >> p & 1)
