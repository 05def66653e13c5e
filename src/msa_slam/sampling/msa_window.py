"""One MSA window optimisation: enumerate the constrained power set, score rho and pi, pick the minimum.

Implements section IV of the paper (eqs. 3-8) with the reference implementation's exact arithmetic
(../docs/msa-reference-semantics.md, step 3 b-e), batched over all candidates of one size:

- `exact` keeps the reference's floating-point path for pi (numpy.gradient's non-uniform formula in its
  operation order, C = J^T J, numpy.linalg.eigh on that matrix, scaled eigen-directions compared by
  BLAS dot products), so it selects the same subsets as the reference on the same machine; where
  rounding could change the choice (another CPU's BLAS kernel), the window is flagged ambiguous
  (msa_ambiguity.py, checked against the fast path and perturbed eigen-decompositions).
- `fast` shares everything that depends only on the window: with A the candidate's gradient operator and
  G_S its block of the window's descriptor Gram matrix, C = A G_S A^T and
  e_j^2 = (a_{j+1} - a_j)^T G_S (a_{j+1} - a_j) with a_j = sqrt(lam_j) v_j, so a candidate costs O(m^3)
  instead of O(m^2 M). Algebraically equal, numerically not bit-identical (pi is ill-conditioned).
"""

from __future__ import annotations

import itertools
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numba import njit

from msa_slam.sampling.msa_ambiguity import decision_margin

MODES = ("exact", "fast")
EIGENVALUE_FLOOR = 1e-6
C_CLIP = 1e6
PROBES = 3  # rounding-level perturbations of each candidate's C for the ambiguity check (msa_ambiguity)
PROBE_SCALE = 1e-13  # their relative size: ~450 ulp, beyond any reordering of a BLAS kernel's sums
PARALLEL_MIN_CANDIDATES = 1500  # below this a thread hand-off costs more than it saves
MAX_THREADS = 4
_POOL: tuple[int, ThreadPoolExecutor] | None = None


@dataclass(frozen=True)
class WindowResult:
    """The chosen subset (positions into the window, starting with 0) and the work done.

    `ambiguous` is True when rounding-level changes of pi could change the choice (msa_ambiguity);
    `margin` is the runner-up's relative score excess over the winner (inf with one candidate).
    Neither takes part in equality: two results are equal when they choose the same subset.
    """

    positions: tuple[int, ...]
    candidates: int
    ambiguous: bool = field(default=False, compare=False)
    margin: float = field(default=float("inf"), compare=False)


@dataclass(frozen=True)
class ScoreWeights:
    """alpha, beta of eq. (8); the paper's ablations switch rho or pi off."""

    alpha: float = 1.0
    beta: float = 1.0
    use_rho: bool = True
    use_pi: bool = True


@lru_cache(maxsize=64)
def subsets_by_size(n: int) -> tuple[np.ndarray, ...]:
    """All candidate subsets of n window positions, grouped by size m = 2..n-1, in the reference order.

    A subset always starts at position 0; the rest is an itertools.combinations of 1..n-1.
    """
    groups = []
    for size in range(2, n):
        combos = np.array(list(itertools.combinations(range(1, n), size - 1)), dtype=np.intp)
        groups.append(np.hstack([np.zeros((len(combos), 1), dtype=np.intp), combos]))
    for g in groups:
        g.setflags(write=False)
    return tuple(groups)


def vector_similarity(a: np.ndarray, b: np.ndarray) -> float:
    """Redundancy similarity of the reference: 1/(1+L2) for vectors; summed per column for 2-D arrays."""
    if a.ndim == 1:
        return 1.0 / (1.0 + np.linalg.norm(a - b))
    return float(np.sum(1.0 / (1.0 + np.linalg.norm(a - b, axis=0))))


def _dot_norms(rows: np.ndarray) -> np.ndarray:
    """sqrt(x . x) for each row via BLAS dot products: numpy.linalg.norm's arithmetic for 1-D arrays."""
    rows = np.ascontiguousarray(rows)
    return np.sqrt((rows[:, None, :] @ rows[:, :, None])[:, 0, 0])


def _pairwise_exact(translations: np.ndarray, descriptors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances and similarities of all pairs with the arithmetic the reference uses per pair.

    numpy.linalg.norm of a vector is a BLAS dot product; per-column norms of 2-D descriptors reduce over
    rings row by row, and the per-sector sum is numpy's pairwise sum: all kept, so each entry equals
    `vector_similarity` / `numpy.linalg.norm` called on the pair.
    """
    n = len(translations)
    upper_i, upper_j = np.triu_indices(n, 1)
    dist = np.zeros((n, n))
    dist[upper_i, upper_j] = _dot_norms(translations[upper_j] - translations[upper_i])
    diff = descriptors[upper_j] - descriptors[upper_i]
    sim = np.zeros((n, n))
    if descriptors.ndim == 2:
        sim[upper_i, upper_j] = 1.0 / (1.0 + _dot_norms(diff))
    else:
        sim[upper_i, upper_j] = np.sum(1.0 / (1.0 + np.sqrt(np.add.reduce(diff * diff, axis=1))), axis=-1)
    dist += dist.T
    sim += sim.T
    return dist, sim


@njit(cache=True)
def _pairwise_fast(translations: np.ndarray, descriptors: np.ndarray):  # pragma: no cover
    """Distances and similarities for all pairs, compiled (same values up to rounding).

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


def _minmax(values: np.ndarray) -> np.ndarray:
    lo, hi = values.min(), values.max()
    if hi == lo:
        return np.ones_like(values)
    return (values - lo) / (hi - lo)


def _redundancy(subsets: np.ndarray, sim: np.ndarray) -> np.ndarray:
    """rho: mean similarity of consecutive members (summed left to right, as the reference does)."""
    pair_sims = sim[subsets[:, 1:], subsets[:, :-1]]
    return np.mean(pair_sims, axis=1)


def _normalised_mean_steps(e: np.ndarray) -> np.ndarray:
    """pi from the eigen-step lengths e (C, m-1): min-max normalise each row, then average."""
    lo = e.min(axis=1, keepdims=True)
    hi = e.max(axis=1, keepdims=True)
    return np.mean((e - lo) / (hi - lo + EIGENVALUE_FLOOR), axis=1)


def _sanitize(c: np.ndarray) -> np.ndarray:
    """The reference's guard: non-finite information matrices are cleaned and clipped."""
    bad = ~np.isfinite(c).all(axis=(1, 2))
    if bad.any():
        c[bad] = np.clip(np.nan_to_num(c[bad]), -C_CLIP, C_CLIP)
    return c


class ExactWorkspace:
    """Reusable scratch buffers for the exact batches.

    Fresh multi-megabyte temporaries per batch cost more in page faults than the arithmetic itself,
    so every large intermediate is written into one of these buffers with `out=` (same arithmetic).
    """

    CHUNK = 24  # candidates per batch (measured: 16-24 keep the batch in cache)

    def __init__(self) -> None:
        self._buffers: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        size = int(np.prod(shape))
        buf = self._buffers.get(name)
        if buf is None or buf.size < size:
            buf = self._buffers[name] = np.empty(size)
        return buf[:size].reshape(shape)


@njit(cache=True)
def _gradient_exact(f: np.ndarray, x: np.ndarray, out: np.ndarray) -> np.ndarray:  # pragma: no cover
    """numpy.gradient(F.T, x, axis=1).T for a stack of (m, M) descriptor blocks F with coordinates x.

    numpy's formulas in its operation order (edge_order 1; a*f[:-2] + b*f[1:-1] + c*f[2:] inside,
    one-sided differences at both ends, the uniform formula when all spacings are equal), compiled
    without floating-point contraction, so each slice is bit-identical to numpy's own call. Writes
    J^T as (C, m, M) into `out` (the memory layout of numpy's result: J is Fortran-ordered there).
    """
    count, m, width = f.shape
    for c in range(count):
        dx0 = x[c, 1] - x[c, 0]
        dxn = x[c, m - 1] - x[c, m - 2]
        uniform = True
        for k in range(1, m - 1):
            if x[c, k + 1] - x[c, k] != dx0:
                uniform = False
        for p in range(width):
            out[c, 0, p] = (f[c, 1, p] - f[c, 0, p]) / dx0
            out[c, m - 1, p] = (f[c, m - 1, p] - f[c, m - 2, p]) / dxn
        for k in range(1, m - 1):
            if uniform:
                for p in range(width):
                    out[c, k, p] = (f[c, k + 1, p] - f[c, k - 1, p]) / (2.0 * dx0)
                continue
            dx1 = x[c, k] - x[c, k - 1]
            dx2 = x[c, k + 1] - x[c, k]
            a = -(dx2) / (dx1 * (dx1 + dx2))
            b = (dx2 - dx1) / (dx1 * dx2)
            cc = dx1 / (dx2 * (dx1 + dx2))
            for p in range(width):
                out[c, k, p] = a * f[c, k - 1, p] + b * f[c, k, p] + cc * f[c, k + 1, p]
    return out


@njit(cache=True)
def _scaled_steps(t: np.ndarray, scale: np.ndarray, out: np.ndarray) -> np.ndarray:  # pragma: no cover
    """T[:, j+1] * sqrt(lam_{j+1}) - T[:, j] * sqrt(lam_j) for each candidate, rows contiguous."""
    count, m, width = t.shape
    for c in range(count):
        for j in range(m - 1):
            for p in range(width):
                out[c, j, p] = t[c, j + 1, p] * scale[c, j + 1] - t[c, j, p] * scale[c, j]
    return out


def _information_exact(subsets: np.ndarray, x: np.ndarray, flat: np.ndarray,
                       workspace: ExactWorkspace) -> np.ndarray:
    """pi for candidates of one size with the reference's arithmetic (stacked, one eigh per batch)."""
    chunk = workspace.CHUNK
    return np.concatenate([
        _information_exact_batch(subsets[i:i + chunk], x[i:i + chunk], flat, workspace)
        for i in range(0, len(subsets), chunk)])


def _information_exact_batch(subsets: np.ndarray, x: np.ndarray, flat: np.ndarray,
                             ws: ExactWorkspace) -> np.ndarray:
    count, m = subsets.shape
    width = flat.shape[1]
    f = np.take(flat, subsets, axis=0, out=ws.get("f", (count, m, width)), mode="clip")  # F, unbuffered
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        jt = _gradient_exact(f, x, ws.get("jt", (count, m, width)))
        c = _sanitize(jt @ jt.transpose(0, 2, 1))  # C = J^T J
    lam, v = np.linalg.eigh(c)
    lam[lam < 0] = 0
    lam += EIGENVALUE_FLOOR
    t = ws.get("t", (count, m, width))  # (F^T V)^T: the reference's T, stored row per eigen-direction
    np.matmul(f.transpose(0, 2, 1), v, out=t.transpose(0, 2, 1))
    steps = _scaled_steps(t, np.sqrt(lam), ws.get("steps", (count, m - 1, width)))
    e = np.sqrt((steps[:, :, None, :] @ steps[:, :, :, None])[:, :, 0, 0])  # BLAS dot per step
    return _normalised_mean_steps(e)


@lru_cache(maxsize=64)
def padded_subsets(n: int) -> tuple[np.ndarray, np.ndarray]:
    """All candidate subsets of n positions in the reference order as one (K, n-1) array padded with -1,
    and their sizes (for the compiled fast path)."""
    groups = subsets_by_size(n)
    table = np.full((sum(len(g) for g in groups), n - 1), -1, dtype=np.int64)
    sizes = np.empty(len(table), dtype=np.int64)
    row = 0
    for g in groups:
        table[row:row + len(g), :g.shape[1]] = g
        sizes[row:row + len(g)] = g.shape[1]
        row += len(g)
    return table, sizes


@njit(cache=True)
def _information_gram(members: np.ndarray, m: int, dist: np.ndarray, gram: np.ndarray,
                      scratch: np.ndarray, probes: int):  # pragma: no cover
    """pi of one candidate through the window's Gram matrix G: C = A G_S A^T, e_j^2 = d_j^T G_S d_j.

    A is numpy.gradient's (tridiagonal) stencil for the candidate's spacing, so J^T = A F; its three
    diagonals are `lower`, `diag`, `upper` (row k uses columns k-1, k, k+1). Returns (pi, lowest, highest):
    the extremes of pi over `probes` eigen-decompositions of C perturbed by PROBE_SCALE (and pi itself).
    """
    lower, diag, upper = scratch[0, :m], scratch[1, :m], scratch[2, :m]
    g, h = scratch[6:6 + m, :m], scratch[6 + m:6 + 2 * m, :m]
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
    # h = A G
    for k in range(m):
        for j in range(m):
            v = diag[k] * g[k, j]
            if k > 0:
                v += lower[k] * g[k - 1, j]
            if k < m - 1:
                v += upper[k] * g[k + 1, j]
            h[k, j] = v
    c = np.empty((m, m))  # (A G) A^T
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
def _pi_of_information(c: np.ndarray, g: np.ndarray, m: int, scratch: np.ndarray) -> float:  # pragma: no cover
    """pi from the information matrix C and the candidate's Gram block G_S (e_j^2 = d_j^T G_S d_j)."""
    scale, d, e = scratch[3, :m], scratch[4, :m], scratch[5, :m - 1]
    lam, vec = np.linalg.eigh(c)
    for j in range(m):
        scale[j] = np.sqrt(max(lam[j], 0.0) + EIGENVALUE_FLOOR)
    for j in range(m - 1):
        for i in range(m):
            d[i] = vec[i, j + 1] * scale[j + 1] - vec[i, j] * scale[j]
        total = 0.0
        for i in range(m):
            row = 0.0
            for k in range(m):
                row += g[i, k] * d[k]
            total += d[i] * row
        e[j] = np.sqrt(max(total, 0.0))
    lo, hi = e.min(), e.max()
    total = 0.0
    for j in range(m - 1):
        total += (e[j] - lo) / (hi - lo + EIGENVALUE_FLOOR)
    return total / (m - 1)


@njit(cache=True)
def _feasible_and_redundancy(table: np.ndarray, sizes: np.ndarray, dist: np.ndarray, sim: np.ndarray,
                             dmin: float, dmax: float):  # pragma: no cover
    """Rows of the subsets whose consecutive steps lie in [dmin, dmax], and their rho."""
    count = len(table)
    keep = np.zeros(count, dtype=np.bool_)
    rho = np.zeros(count)
    for row in range(count):
        m = sizes[row]
        members = table[row]
        feasible = True
        total = 0.0
        for k in range(m - 1):
            d = dist[members[k], members[k + 1]]
            if d < dmin or d > dmax:
                feasible = False
                break
            total += sim[members[k + 1], members[k]]
        if feasible:
            keep[row] = True
            rho[row] = total / (m - 1)
    rows = np.flatnonzero(keep)
    return rows, rho[rows]


@njit(cache=True, nogil=True)
def _information_many(table: np.ndarray, sizes: np.ndarray, rows: np.ndarray, dist: np.ndarray,
                      gram: np.ndarray, probes: int) -> np.ndarray:  # pragma: no cover
    """(3, rows): pi of the given candidate rows, and its lowest and highest value over the probes."""
    out = np.zeros((3, len(rows)))
    width = table.shape[1] + 1
    scratch = np.empty((6 + 2 * width, width))
    for i in range(len(rows)):
        m = sizes[rows[i]]
        if m > 2:
            out[0, i], out[1, i], out[2, i] = _information_gram(table[rows[i]], m, dist, gram, scratch, probes)
    return out


def _thread_pool(workers: int) -> ThreadPoolExecutor:
    """One pool per process (a pool inherited through fork has no threads behind it)."""
    global _POOL
    if _POOL is None or _POOL[0] != os.getpid():
        _POOL = (os.getpid(), ThreadPoolExecutor(max_workers=workers, thread_name_prefix="msa-fast"))
    return _POOL[1]


def _information_threaded(table: np.ndarray, sizes: np.ndarray, rows: np.ndarray, dist: np.ndarray,
                          gram: np.ndarray, probes: int = PROBES) -> np.ndarray:
    """`_information_many` of all rows; large windows (N >= ~13) are split across threads (no GIL)."""
    workers = min(os.cpu_count() or 1, MAX_THREADS)
    if workers < 2 or len(rows) < PARALLEL_MIN_CANDIDATES:
        return _information_many(table, sizes, rows, dist, gram, probes)
    pool = _thread_pool(workers)
    parts = np.array_split(rows, workers)
    return np.concatenate(list(pool.map(lambda part: _information_many(table, sizes, part, dist, gram, probes),
                                        parts)), axis=1)


def _optimise_fast(translations: np.ndarray, descriptors: np.ndarray, dmin: float, dmax: float,
                   weights: ScoreWeights) -> WindowResult:
    n = len(translations)
    blocks = descriptors.reshape(n, -1, 1) if descriptors.ndim == 2 else descriptors
    dist, sim = _pairwise_fast(np.ascontiguousarray(translations), np.ascontiguousarray(blocks))
    table, sizes = padded_subsets(n)
    rows, rho = _feasible_and_redundancy(table, sizes, dist, sim, dmin, dmax)
    if rows.size == 0:
        return WindowResult((0, n - 1), 1)
    probed = _information_threaded(table, sizes, rows, dist, _gram(descriptors)) if weights.use_pi else None
    pi, pi_low, pi_high = probed if probed is not None else (None, None, None)
    best, ambiguous, margin = _decide(int(rows.size), rho if weights.use_rho else None, pi, pi_low, pi_high, weights)
    row = rows[best]
    return WindowResult(tuple(int(p) for p in table[row, :sizes[row]]), int(rows.size), ambiguous, margin)


def _optimise_exact(translations: np.ndarray, descriptors: np.ndarray, dmin: float, dmax: float,
                    weights: ScoreWeights, workspace: ExactWorkspace) -> WindowResult:
    n = len(translations)
    dist, sim = _pairwise_exact(translations, descriptors)
    allowed = (dist >= dmin) & (dist <= dmax)
    groups = []
    for subsets in subsets_by_size(n):
        keep = allowed[subsets[:, :-1], subsets[:, 1:]].all(axis=1)
        if keep.any():
            groups.append(subsets[keep])
    if not groups:
        return WindowResult((0, n - 1), 1)
    count = sum(len(g) for g in groups)
    flat = descriptors.reshape(n, -1)
    rho = np.concatenate([_redundancy(subsets, sim) for subsets in groups]) if weights.use_rho else None
    pi = pi_low = pi_high = None
    if weights.use_pi:
        pi = np.concatenate([np.zeros(len(subsets)) if subsets.shape[1] == 2 else
                             _information_exact(subsets, dist[0, subsets], flat, workspace) for subsets in groups])
        pi_low, pi_high = _fast_path_extremes(pi, dist, sim, dmin, dmax, _gram(descriptors))
    best, ambiguous, margin = _decide(count, rho, pi, pi_low, pi_high, weights)
    for subsets in groups:
        if best < len(subsets):
            return WindowResult(tuple(int(p) for p in subsets[best]), count, ambiguous, margin)
        best -= len(subsets)
    raise AssertionError("unreachable: best index beyond the candidate list")


def _gram(descriptors: np.ndarray) -> np.ndarray:
    flat = descriptors.reshape(len(descriptors), -1)
    return flat @ flat.T


def _fast_path_extremes(pi: np.ndarray, dist: np.ndarray, sim: np.ndarray, dmin: float, dmax: float,
                        gram: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Extremes of the exact pi under rounding: the fast path's value and its probes' shifts.

    The fast path computes pi by another floating-point route (the Gram shortcut); where it or its
    perturbed eigen-decompositions land elsewhere, the exact value could too on another machine.
    """
    table, sizes = padded_subsets(len(dist))
    rows, _ = _feasible_and_redundancy(table, sizes, dist, sim, dmin, dmax)
    fast, low, high = _information_threaded(table, sizes, rows, dist, gram)
    return np.minimum(fast, pi + (low - fast)), np.maximum(fast, pi + (high - fast))


def _decide(count: int, rho: np.ndarray | None, pi: np.ndarray | None, pi_low: np.ndarray | None,
            pi_high: np.ndarray | None, weights: ScoreWeights) -> tuple[int, bool, float]:
    """The first candidate with the smallest eq. (8) score, whether rounding could change it, its margin.

    rho or pi is None when its ablation is on (its normalised value is then 0 for every candidate).
    """
    rho_hat = _minmax(rho) if rho is not None else np.zeros(count)
    pi_hat = _minmax(pi) if pi is not None else np.zeros(count)
    score = (weights.alpha + rho_hat) / (weights.beta + pi_hat)
    best = int(np.argmin(score))
    ambiguous, margin = decision_margin(score, rho, pi, pi_low, pi_high, weights.alpha, weights.beta, best)
    return best, ambiguous, margin


def optimise_window(translations: np.ndarray, descriptors: np.ndarray, dmin: float, dmax: float,
                    weights: ScoreWeights, mode: str = "exact",
                    workspace: ExactWorkspace | None = None) -> WindowResult:
    """Choose the subset of the n window members that minimises (alpha + rho^) / (beta + pi^).

    translations (n, 3) and descriptors (n, ...) are the window members in window order; pass a
    workspace to reuse scratch buffers across windows (exact mode).
    """
    if mode == "fast":
        return _optimise_fast(translations, descriptors, dmin, dmax, weights)
    return _optimise_exact(translations, descriptors, dmin, dmax, weights, workspace or ExactWorkspace())
