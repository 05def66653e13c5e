"""One MSA window optimisation, by mode: `exact` (the reference's arithmetic) or `fast` (Gram path)."""

from __future__ import annotations

import numpy as np

from msa_slam.sampling.msa.exact import ExactWorkspace, optimise_exact
from msa_slam.sampling.msa.fast import optimise_fast
from msa_slam.sampling.msa.terms import ScoreWeights, WindowResult


def optimise_window(
    translations: np.ndarray,
    descriptors: np.ndarray,
    dmin: float,
    dmax: float,
    weights: ScoreWeights,
    mode: str = "exact",
    workspace: ExactWorkspace | None = None,
    pi: str = "reference",
) -> WindowResult:
    """Choose the subset of the n window members that minimises (alpha + rho^) / (beta + pi^), eq. (8).

    translations (n, 3) and descriptors (n, ...) are the window members in window order; pass a
    workspace to reuse scratch buffers across windows (exact mode); pi is one of params.PI_DEFINITIONS.
    terms.optimise_window_literal is the same choice computed one subset at a time.
    """
    if mode == "fast":
        return optimise_fast(translations, descriptors, dmin, dmax, weights, pi)
    return optimise_exact(translations, descriptors, dmin, dmax, weights, workspace or ExactWorkspace(), pi)


def fell_back(result: WindowResult, translations: np.ndarray, dmin: float, dmax: float) -> bool:
    """True when no subset met the bounds and the window's first and last member were taken (the reference's
    fallback). Both optimisers return that as a single candidate (0, n-1), as they would a pair (0, n-1)
    that alone met them, so the pair's own distance tells the two apart."""
    n = len(translations)
    if result.candidates != 1 or result.positions != (0, n - 1):
        return False
    return not dmin <= float(np.linalg.norm(translations[-1] - translations[0])) <= dmax
