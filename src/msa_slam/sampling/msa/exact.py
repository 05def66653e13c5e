"""Exact mode: the reference's floating-point path for every candidate, batched by subset size.

Each quantity is computed with the operations the reference applies to one subset (terms.py), in the
same order, so a batch gives bit-identical values: numpy.gradient's non-uniform formula, C = J^T J,
numpy.linalg.eigh on that matrix, scaled eigen-directions compared through BLAS dot products. It
therefore selects the reference's subsets on the same machine; the fast path's values and probes bound
how far another machine's rounding could move pi (decision.py, docs/msa.md).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit

from msa_slam.sampling.msa import fast
from msa_slam.sampling.msa.canonical import canonicalise
from msa_slam.sampling.msa.decision import decide
from msa_slam.sampling.msa.powerset import feasible_subsets, subsets_by_size
from msa_slam.sampling.msa.terms import C_CLIP, EIGENVALUE_FLOOR, ScoreWeights, WindowResult


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


def _dot_norms(rows: np.ndarray) -> np.ndarray:
    """sqrt(x . x) for each row via BLAS dot products: numpy.linalg.norm's arithmetic for 1-D arrays."""
    rows = np.ascontiguousarray(rows)
    return np.sqrt((rows[:, None, :] @ rows[:, :, None])[:, 0, 0])


def pairwise(translations: np.ndarray, descriptors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances and similarities of all pairs, each entry equal to numpy.linalg.norm / terms.similarity
    called on the pair (per-column norms reduce over rings row by row; the per-sector sum is numpy's)."""
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


def _redundancy(subsets: np.ndarray, sim: np.ndarray) -> np.ndarray:
    """rho of every subset: mean similarity of consecutive members (summed left to right)."""
    return np.mean(sim[subsets[:, 1:], subsets[:, :-1]], axis=1)


def _sanitize(c: np.ndarray) -> np.ndarray:
    """The reference's guard: non-finite information matrices are cleaned and clipped."""
    bad = ~np.isfinite(c).all(axis=(1, 2))
    if bad.any():
        c[bad] = np.clip(np.nan_to_num(c[bad]), -C_CLIP, C_CLIP)
    return c


@njit(cache=True, error_model="numpy")
def _gradient(f: np.ndarray, x: np.ndarray, out: np.ndarray) -> np.ndarray:  # pragma: no cover
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


def _information(
    subsets: np.ndarray, x: np.ndarray, flat: np.ndarray, workspace: ExactWorkspace, canonical: bool = False
) -> np.ndarray:
    """pi for candidates of one size (m > 2), in batches of CHUNK (one stacked eigh per batch)."""
    chunk = workspace.CHUNK
    return np.concatenate(
        [
            _information_batch(subsets[i : i + chunk], x[i : i + chunk], flat, workspace, canonical)
            for i in range(0, len(subsets), chunk)
        ]
    )


@njit(cache=True)
def _canonicalise_stack(lam: np.ndarray, v: np.ndarray) -> None:  # pragma: no cover
    """canonical.canonicalise on every eigen-decomposition of a stack (in place)."""
    count, m = lam.shape
    work = np.empty((m + 1, m))
    for c in range(count):
        canonicalise(lam[c], v[c], m, work)


def _information_batch(
    subsets: np.ndarray, x: np.ndarray, flat: np.ndarray, ws: ExactWorkspace, canonical: bool
) -> np.ndarray:
    count, m = subsets.shape
    width = flat.shape[1]
    f = np.take(flat, subsets, axis=0, out=ws.get("f", (count, m, width)), mode="clip")  # F, unbuffered
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        jt = _gradient(f, x, ws.get("jt", (count, m, width)))
        c = _sanitize(jt @ jt.transpose(0, 2, 1))  # C = J^T J
    lam, v = np.linalg.eigh(c)
    if canonical:
        _canonicalise_stack(lam, v)
    lam[lam < 0] = 0
    lam += EIGENVALUE_FLOOR
    t = ws.get("t", (count, m, width))  # (F^T V)^T: the reference's T, stored row per eigen-direction
    np.matmul(f.transpose(0, 2, 1), v, out=t.transpose(0, 2, 1))
    steps = _scaled_steps(t, np.sqrt(lam), ws.get("steps", (count, m - 1, width)))
    e = np.sqrt((steps[:, :, None, :] @ steps[:, :, :, None])[:, :, 0, 0])  # BLAS dot per step
    lo, hi = e.min(axis=1, keepdims=True), e.max(axis=1, keepdims=True)
    return np.mean((e - lo) / (hi - lo + EIGENVALUE_FLOOR), axis=1)


def fast_path_extremes(
    pi: np.ndarray,
    dist: np.ndarray,
    sim: np.ndarray,
    dmin: float,
    dmax: float,
    gram: np.ndarray,
    canonical: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Extremes of the exact pi under rounding: the fast path's value and its probes' shifts.

    The fast path computes pi by another floating-point route (the Gram shortcut); where it or its
    perturbed eigen-decompositions land elsewhere, the exact value could too on another machine.
    """
    masks, _ = feasible_subsets(dist, sim, dmin, dmax)
    value, low, high = fast.information_rows(masks, dist, gram, fast.PROBES, canonical, numba.get_num_threads())
    return np.minimum(value, pi + (low - value)), np.maximum(value, pi + (high - value))


def optimise_exact(
    translations: np.ndarray,
    descriptors: np.ndarray,
    dmin: float,
    dmax: float,
    weights: ScoreWeights,
    workspace: ExactWorkspace,
    pi_definition: str = "reference",
) -> WindowResult:
    """The window's choice with the reference's arithmetic (and its ambiguity)."""
    canonical = pi_definition == "canonical"
    n = len(translations)
    dist, sim = pairwise(translations, descriptors)
    allowed = (dist >= dmin) & (dist <= dmax)  # eq. (7) on every pair, then on every consecutive pair
    groups = [s[keep] for s in subsets_by_size(n) if (keep := allowed[s[:, :-1], s[:, 1:]].all(axis=1)).any()]
    if not groups:
        return WindowResult((0, n - 1), 1)
    count = sum(len(g) for g in groups)
    flat = descriptors.reshape(n, -1)
    rho = np.concatenate([_redundancy(subsets, sim) for subsets in groups]) if weights.use_rho else None
    pi = pi_low = pi_high = None
    if weights.use_pi:
        pi = np.concatenate(
            [
                np.zeros(len(subsets))
                if subsets.shape[1] == 2
                else _information(subsets, dist[0, subsets], flat, workspace, canonical)
                for subsets in groups
            ]
        )
        pi_low, pi_high = fast_path_extremes(pi, dist, sim, dmin, dmax, fast.gram(descriptors), canonical)
    best, ambiguous, margin = decide(count, rho, pi, pi_low, pi_high, weights)
    for subsets in groups:
        if best < len(subsets):
            return WindowResult(tuple(int(p) for p in subsets[best]), count, ambiguous, margin)
        best -= len(subsets)
    raise AssertionError("unreachable: best index beyond the candidate list")
