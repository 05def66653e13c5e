"""The terms of one MSA window optimisation, one subset at a time: the readable definition.

Paper section IV-B/C (eqs. 3-8) with the choices of the authors' reference implementation where the
paper leaves them open (docs/msa.md). The sampler does not call these functions: exact.py and fast.py
compute the same quantities batched over all candidates. This module is the oracle the tests compare
them with and the one-at-a-time baseline `benchmarks/bench_msa.py` measures their speed-up from.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from msa_slam.sampling.msa.canonical import canonicalise

EIGENVALUE_FLOOR = 1e-6  # added to every eigenvalue of C, and to the denominator of e's normalisation
C_CLIP = 1e6  # a non-finite C (coincident distances) is cleaned and clipped to this, as the reference does


@dataclass(frozen=True)
class ScoreWeights:
    """alpha, beta of eq. (8); the paper's ablations switch rho or pi off."""

    alpha: float = 1.0
    beta: float = 1.0
    use_rho: bool = True
    use_pi: bool = True


@dataclass(frozen=True)
class WindowResult:
    """The chosen subset (positions into the window, starting with 0) and the work done.

    `ambiguous` is True when rounding-level changes of pi could change the choice (decision.py);
    `margin` is the runner-up's relative score excess over the winner (inf with one candidate).
    Neither takes part in equality: two results are equal when they choose the same subset.
    """

    positions: tuple[int, ...]
    candidates: int
    ambiguous: bool = field(default=False, compare=False)
    margin: float = field(default=float("inf"), compare=False)


def constrained_power_set(translations: np.ndarray, dmin: float, dmax: float) -> list[tuple[int, ...]]:
    """Eq. (7): the subsets of window positions that start at 0 and whose consecutive poses lie between
    dmin and dmax apart, in the reference's order (by size 2..n-1, then itertools.combinations order).

    The window's last position is a candidate member but never forced in; when no subset qualifies, the
    only candidate is (0, n-1).
    """
    n = len(translations)
    kept = []
    for size in range(2, n):
        for rest in itertools.combinations(range(1, n), size - 1):
            subset = (0,) + rest
            steps = [np.linalg.norm(translations[b] - translations[a]) for a, b in zip(subset, subset[1:])]
            if all(dmin <= s <= dmax for s in steps):
                kept.append(subset)
    return kept or [(0, n - 1)]


def similarity(a: np.ndarray, b: np.ndarray) -> float:
    """Descriptor similarity of the reference: 1/(1+L2) for vectors; summed per column (sector) for 2-D."""
    if a.ndim == 1:
        return 1.0 / (1.0 + np.linalg.norm(a - b))
    return float(np.sum(1.0 / (1.0 + np.linalg.norm(a - b, axis=0))))


def redundancy(descriptors: np.ndarray) -> float:
    """rho, eq. (3): mean similarity of consecutive members (descriptors in subset order)."""
    return float(np.mean([similarity(descriptors[k + 1], descriptors[k]) for k in range(len(descriptors) - 1)]))


def information(translations: np.ndarray, flat: np.ndarray, canonical: bool = False) -> float:
    """pi, eqs. (4)-(5): how much the descriptors change along the path, spread over eigen-directions.

    J is the gradient of the flattened descriptors F (m, M) with respect to the straight-line distance
    from the subset's first pose (numpy.gradient, non-uniform spacing); C = J^T J is the information
    matrix. The reference then compares CONSECUTIVE scaled eigen-directions T_j = F^T v_j sqrt(lam_j):
    e_j = |T_{j+1} - T_j|, min-max normalised, averaged. Two members give pi = 0. `canonical` fixes
    the eigenvectors' signs and the bases of (near-)repeated eigenvalues from C alone (canonical.py).
    """
    m = len(flat)
    if m == 2:
        return 0.0
    x = np.array([np.linalg.norm(translations[k] - translations[0]) for k in range(m)])
    with np.errstate(divide="ignore", invalid="ignore"):
        j = np.gradient(flat.T, x, axis=1)
        c = j.T @ j
    if not np.isfinite(c).all():
        c = np.clip(np.nan_to_num(c), -C_CLIP, C_CLIP)
    lam, v = np.linalg.eigh(c)
    if canonical:
        canonicalise(lam, v, m, np.empty((m + 1, m)))
    lam[lam < 0] = 0
    lam += EIGENVALUE_FLOOR
    t = (flat.T @ v) * np.sqrt(lam)
    e = np.array([np.linalg.norm(t[:, k + 1] - t[:, k]) for k in range(m - 1)])
    e = (e - e.min()) / (e.max() - e.min() + EIGENVALUE_FLOOR)
    return float(np.mean(e))


def minmax(values: np.ndarray) -> np.ndarray:
    """Min-max normalisation across the candidates; all equal values normalise to ones."""
    lo, hi = values.min(), values.max()
    if hi == lo:
        return np.ones_like(values)
    return (values - lo) / (hi - lo)


def score(rho: np.ndarray, pi: np.ndarray, weights: ScoreWeights) -> np.ndarray:
    """Eq. (8) for every candidate: (alpha + rho^) / (beta + pi^), an ablated term being 0."""
    rho_hat = minmax(rho) if weights.use_rho else np.zeros(len(rho))
    pi_hat = minmax(pi) if weights.use_pi else np.zeros(len(pi))
    return (weights.alpha + rho_hat) / (weights.beta + pi_hat)


def optimise_window_literal(
    translations: np.ndarray,
    descriptors: np.ndarray,
    dmin: float,
    dmax: float,
    weights: ScoreWeights,
    canonical: bool = False,
) -> WindowResult:
    """Enumerate, score and choose one subset at a time; the first candidate with the smallest score wins."""
    flat = descriptors.reshape(len(descriptors), -1)
    candidates = constrained_power_set(translations, dmin, dmax)
    rho = np.array([redundancy(descriptors[list(s)]) for s in candidates])
    pi = np.array([information(translations[list(s)], flat[list(s)], canonical) for s in candidates])
    return WindowResult(candidates[int(np.argmin(score(rho, pi, weights)))], len(candidates))
