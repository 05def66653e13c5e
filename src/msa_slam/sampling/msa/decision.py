"""The window's choice (eq. 8's minimum) and whether rounding could change it: score intervals from
rounding-level changes of pi.

pi (docs/msa.md, terms.information) compares consecutive eigenvectors of C = J^T J. An
eigenvector's sign is arbitrary: LAPACK fixes it through intermediate quantities that can sit at a
rounding-level tie, so a perturbation of C by a few ulps (another BLAS kernel, another CPU) can flip a
sign, even between well-separated eigenvalues, and move pi by up to ~0.2; near-equal eigenvalues make
the eigenvectors themselves unstable. No bound computed from the eigenvalue gaps alone can see the sign
flips, so the sensitivity is measured: each candidate's C is eigen-decomposed again after PROBES
perturbations of relative size PROBE_SCALE (~450 ulp, far beyond what reordering a BLAS kernel's sums
does), and pi is taken to lie anywhere between the extremes seen (fast.information_gram).
Continuous rounding noise adds PI_ATOL to pi and RHO_RTOL (relative) to rho.

A window is ambiguous when some other candidate's lowest possible score reaches the winner's highest
possible score, the min-max normalisations and eq. (8) being evaluated in interval arithmetic. It is a
screen, not a proof: a flip that none of the probes provokes goes unseen, which the parity tests
measure (every window that flips under a random perturbation of C must have been flagged).

Compiled: in numpy the screen's two dozen array operations cost 0.1 ms of an N = 10 window (a fifth of
it). Each value is computed with terms.score's and terms.minmax's operations, element by element, so
the scores, the winner and the verdict are those of the numpy definitions (a test compares them).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from msa_slam.sampling.msa.terms import ScoreWeights

PI_ATOL = 1e-9  # pi lies in [0, 1]; continuous rounding of pi stays far below this
RHO_RTOL = 1e-12  # rho is a mean of 1/(1+norm) terms: a few ulp per term


@njit(cache=True)
def minmax_bounds(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """Bounds of the min-max normalised values when value k may lie anywhere in [low_k, high_k].

    Mirrors terms.minmax: all values equal normalise to ones.
    """
    if np.array_equal(low, high) and low.min() == low.max():
        return np.ones_like(low), np.ones_like(low)
    smallest_min, largest_min = low.min(), high.min()  # where the minimum can lie
    smallest_max, largest_max = low.max(), high.max()
    narrowest, widest = smallest_max - largest_min, largest_max - smallest_min
    if narrowest <= 0:  # the values may all coincide: any normalised value in [0, 1] is possible
        return np.zeros_like(low), np.ones_like(low)
    lowest = np.empty_like(low)
    highest = np.empty_like(low)
    for k in range(len(low)):
        lowest[k] = min(max(max(low[k] - largest_min, 0.0) / widest, 0.0), 1.0)
        highest[k] = min(max((high[k] - smallest_min) / narrowest, 0.0), 1.0)
    return lowest, highest


@njit(cache=True)
def _normalised(values: np.ndarray, used: bool) -> np.ndarray:  # pragma: no cover
    """terms.minmax (ones when all values are equal), or zeros when the term is ablated."""
    out = np.zeros(len(values))
    if not used:
        return out
    lo, hi = values.min(), values.max()
    if hi == lo:
        return np.ones(len(values))
    for k in range(len(values)):
        out[k] = (values[k] - lo) / (hi - lo)
    return out


@njit(cache=True)
def _margin(
    score: np.ndarray,
    rho: np.ndarray,
    pi: np.ndarray,
    pi_low: np.ndarray,
    pi_high: np.ndarray,
    use_rho: bool,
    use_pi: bool,
    alpha: float,
    beta: float,
    best: int | np.integer,
):  # pragma: no cover
    """decision_margin with unused terms flagged instead of None (their arrays are then ignored)."""
    count = len(score)
    if count < 2:
        return False, np.inf
    runner_up = np.inf
    for k in range(count):
        if k != best:
            runner_up = min(runner_up, score[k])
    margin = runner_up / score[best] - 1.0
    rho_lo, rho_hi = np.zeros(count), np.zeros(count)
    if use_rho:
        slack = RHO_RTOL * np.abs(rho)
        rho_lo, rho_hi = minmax_bounds(rho - slack, rho + slack)
    pi_lo, pi_hi = np.zeros(count), np.zeros(count)
    if use_pi:
        pi_lo, pi_hi = minmax_bounds(np.minimum(pi, pi_low) - PI_ATOL, np.maximum(pi, pi_high) + PI_ATOL)
    highest = (alpha + rho_hi[best]) / (beta + pi_lo[best])
    for k in range(count):
        if k != best and (alpha + rho_lo[k]) / (beta + pi_hi[k]) <= highest:
            return True, margin
    return False, margin


@njit(cache=True)
def _decide(
    rho: np.ndarray,
    pi: np.ndarray,
    pi_low: np.ndarray,
    pi_high: np.ndarray,
    use_rho: bool,
    use_pi: bool,
    alpha: float,
    beta: float,
    score_rho: bool,
    score_pi: bool,
):  # pragma: no cover
    """decide on arrays: use_rho/use_pi say whether rho/pi were given (zeros otherwise), score_rho/score_pi
    whether eq. (8) normalises them (ScoreWeights)."""
    rho_hat, pi_hat = _normalised(rho, score_rho), _normalised(pi, score_pi)
    scores = np.empty(len(rho_hat))
    for k in range(len(scores)):
        scores[k] = (alpha + rho_hat[k]) / (beta + pi_hat[k])
    best = np.argmin(scores)
    ambiguous, margin = _margin(scores, rho, pi, pi_low, pi_high, use_rho, use_pi, alpha, beta, best)
    return best, ambiguous, margin


def _array(values: np.ndarray | None, count: int) -> np.ndarray:
    return np.zeros(count) if values is None else np.ascontiguousarray(values, dtype=np.float64)


def decision_margin(
    score: np.ndarray,
    rho: np.ndarray | None,
    pi: np.ndarray | None,
    pi_low: np.ndarray | None,
    pi_high: np.ndarray | None,
    alpha: float,
    beta: float,
    best: int,
) -> tuple[bool, float]:
    """(ambiguous, margin) of the choice `best` among candidates with eq. (8) scores `score`.

    rho and pi are the candidates' raw redundancy and information, None when an ablation switches
    one off (its normalised value is 0); pi_low/pi_high are the probed extremes of pi. margin is the
    runner-up's relative score excess over the winner.
    """
    count = len(score)
    ambiguous, margin = _margin(
        _array(score, count),
        _array(rho, count),
        _array(pi, count),
        _array(pi_low, count),
        _array(pi_high, count),
        rho is not None,
        pi is not None,
        alpha,
        beta,
        best,
    )
    return bool(ambiguous), float(margin)


def decide(
    count: int,
    rho: np.ndarray | None,
    pi: np.ndarray | None,
    pi_low: np.ndarray | None,
    pi_high: np.ndarray | None,
    weights: ScoreWeights,
) -> tuple[int, bool, float]:
    """The first candidate with the smallest eq. (8) score, whether rounding could change it, its margin.

    rho or pi is None when its ablation is on (its normalised value is then 0 for every candidate).
    """
    best, ambiguous, margin = _decide(
        _array(rho, count),
        _array(pi, count),
        _array(pi_low, count),
        _array(pi_high, count),
        rho is not None,
        pi is not None,
        float(weights.alpha),
        float(weights.beta),
        weights.use_rho,
        weights.use_pi,
    )
    return int(best), bool(ambiguous), float(margin)
