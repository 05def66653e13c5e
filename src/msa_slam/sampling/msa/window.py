"""One MSA window optimisation, by mode: `exact` (the reference's arithmetic) or `fast` (Gram path)."""

from __future__ import annotations

import numpy as np

from msa_slam.sampling.msa.exact import ExactWorkspace, optimise_exact
from msa_slam.sampling.msa.fast import optimise_fast
from msa_slam.sampling.msa.terms import ScoreWeights, WindowResult

MODES = ("exact", "fast")
PI_DEFINITIONS = ("reference", "canonical")  # LAPACK's eigenvectors as they come, or canonical.py's


def optimise_window(translations: np.ndarray, descriptors: np.ndarray, dmin: float, dmax: float,
                    weights: ScoreWeights, mode: str = "exact",
                    workspace: ExactWorkspace | None = None, pi: str = "reference") -> WindowResult:
    """Choose the subset of the n window members that minimises (alpha + rho^) / (beta + pi^), eq. (8).

    translations (n, 3) and descriptors (n, ...) are the window members in window order; pass a
    workspace to reuse scratch buffers across windows (exact mode); pi is one of PI_DEFINITIONS.
    terms.optimise_window_literal is the same choice computed one subset at a time.
    """
    if mode == "fast":
        return optimise_fast(translations, descriptors, dmin, dmax, weights, pi)
    return optimise_exact(translations, descriptors, dmin, dmax, weights, workspace or ExactWorkspace(), pi)
