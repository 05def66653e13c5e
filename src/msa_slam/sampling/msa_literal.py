"""A one-candidate-at-a-time transcription of the MSA window optimisation (the reference's shape).

Not used by the sampler: it is the independent oracle that tests check the batched exact mode
against, and the speed baseline that `benchmarks/bench_msa.py` measures speed-ups from
(../docs/msa-reference-semantics.md, step 3 b-e, written as plainly as possible).
"""

from __future__ import annotations

import itertools

import numpy as np

from msa_slam.sampling.msa_window import ScoreWeights, WindowResult, vector_similarity


def literal_information(members: np.ndarray, flat: np.ndarray) -> float:
    """pi of one subset: gradient of descriptors w.r.t. distance, eigen-directions of J^T J."""
    m = len(members)
    if m == 2:
        return 0.0
    x = np.array([np.linalg.norm(members[k][0] - members[0][0]) for k in range(m)])
    f = np.array([flat_k for _, flat_k in members])
    with np.errstate(divide="ignore", invalid="ignore"):
        j = np.gradient(f.T, x, axis=1)
        c = j.T @ j
    if not np.isfinite(c).all():
        c = np.clip(np.nan_to_num(c), -1e6, 1e6)
    lam, v = np.linalg.eigh(c)
    lam[lam < 0] = 0
    lam += 1e-6
    t = (f.T @ v) * np.sqrt(lam)
    e = np.array([np.linalg.norm(t[:, k + 1] - t[:, k]) for k in range(m - 1)])
    e = (e - e.min()) / (e.max() - e.min() + 1e-6)
    return float(np.mean(e))


def literal_optimise_window(translations: np.ndarray, descriptors: np.ndarray, dmin: float,
                            dmax: float, weights: ScoreWeights) -> WindowResult:
    """Enumerate, filter and score every subset one at a time; return the first minimum."""
    n = len(translations)
    flat = descriptors.reshape(n, -1)
    candidates = []
    for r in range(2, n):
        for combo in itertools.combinations(range(1, n), r - 1):
            subset = (0,) + combo
            steps = [np.linalg.norm(translations[subset[k + 1]] - translations[subset[k]])
                     for k in range(len(subset) - 1)]
            if all(dmin <= s <= dmax for s in steps):
                candidates.append(subset)
    if not candidates:
        candidates = [(0, n - 1)]
    rho, pi = [], []
    for subset in candidates:
        sims = [vector_similarity(descriptors[subset[k + 1]], descriptors[subset[k]])
                for k in range(len(subset) - 1)]
        rho.append(np.mean(sims))
        pi.append(literal_information([(translations[p], flat[p]) for p in subset], flat))

    def normalise(values, enabled):
        values = np.asarray(values)
        if not enabled:
            return np.zeros_like(values)
        lo, hi = values.min(), values.max()
        return np.ones_like(values) if hi == lo else (values - lo) / (hi - lo)

    score = (weights.alpha + normalise(rho, weights.use_rho)) / (weights.beta + normalise(pi, weights.use_pi))
    return WindowResult(candidates[int(np.argmin(score))], len(candidates))
