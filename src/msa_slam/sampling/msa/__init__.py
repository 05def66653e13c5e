"""Minimal Subset Approach (MSA), paper section IV: the sliding-window sampler and its window optimisation.

sampler.py   the state machine of section IV-C (bounds, terms, score, emit, slide) with the reference's counters
terms.py     rho, pi, the constrained power set and the score, one subset at a time (the readable definition)
exact.py     the same terms batched with the reference's floating-point path (default mode)
fast.py      pi through the window's Gram matrix (mode "fast")
decision.py  the winner, and whether rounding could change it (ambiguous windows)
See docs/msa.md.
"""

from msa_slam.sampling.msa.sampler import MSASampler
from msa_slam.sampling.msa.terms import ScoreWeights, WindowResult
from msa_slam.sampling.msa.window import MODES, optimise_window

__all__ = ["MODES", "MSASampler", "ScoreWeights", "WindowResult", "optimise_window"]
