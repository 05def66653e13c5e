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
"""

from __future__ import annotations

import numpy as np

from msa_slam.sampling.msa.terms import ScoreWeights, score

PI_ATOL = 1e-9  # pi lies in [0, 1]; continuous rounding of pi stays far below this
RHO_RTOL = 1e-12  # rho is a mean of 1/(1+norm) terms: a few ulp per term


def minmax_bounds(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    lowest = np.maximum(low - largest_min, 0.0) / widest
    highest = (high - smallest_min) / narrowest
    return np.clip(lowest, 0.0, 1.0), np.clip(highest, 0.0, 1.0)


def decision_margin(score: np.ndarray, rho: np.ndarray | None, pi: np.ndarray | None,
                    pi_low: np.ndarray | None, pi_high: np.ndarray | None, alpha: float, beta: float,
                    best: int) -> tuple[bool, float]:
    """(ambiguous, margin) of the choice `best` among candidates with eq. (8) scores `score`.

    rho and pi are the candidates' raw redundancy and information, None when an ablation switches
    one off (its normalised value is 0); pi_low/pi_high are the probed extremes of pi. margin is the
    runner-up's relative score excess over the winner.
    """
    count = len(score)
    if count < 2:
        return False, float("inf")
    margin = float(np.min(np.delete(score, best)) / score[best] - 1.0)
    if rho is None:
        rho_lo = rho_hi = np.zeros(count)
    else:
        slack = RHO_RTOL * np.abs(rho)
        rho_lo, rho_hi = minmax_bounds(rho - slack, rho + slack)
    if pi is None:
        pi_lo = pi_hi = np.zeros(count)
    else:
        pi_lo, pi_hi = minmax_bounds(np.minimum(pi, pi_low) - PI_ATOL, np.maximum(pi, pi_high) + PI_ATOL)
    lowest = (alpha + rho_lo) / (beta + pi_hi)
    highest = (alpha + rho_hi) / (beta + pi_lo)
    others = np.delete(lowest, best)
    return bool((others <= highest[best]).any()), margin


def decide(count: int, rho: np.ndarray | None, pi: np.ndarray | None, pi_low: np.ndarray | None,
           pi_high: np.ndarray | None, weights: ScoreWeights) -> tuple[int, bool, float]:
    """The first candidate with the smallest eq. (8) score, whether rounding could change it, its margin.

    rho or pi is None when its ablation is on (its normalised value is then 0 for every candidate).
    """
    zeros = np.zeros(count)
    scores = score(zeros if rho is None else rho, zeros if pi is None else pi, weights)
    best = int(np.argmin(scores))
    ambiguous, margin = decision_margin(scores, rho, pi, pi_low, pi_high, weights.alpha, weights.beta, best)
    return best, ambiguous, margin
