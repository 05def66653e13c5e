"""Minimal Subset Approach (MSA), paper section IV: the sliding-window sampler and its window optimisation.

params.py          its parameters (pydantic), checked before a sampler is built
sampler.py         the state machine of section IV-C (bounds, terms, score, emit, slide) with the reference's counters
window.py          one window optimisation, by mode (exact or fast)
terms.py           rho, pi, the constrained power set and the score, one subset at a time (the readable definition)
powerset.py        the candidate subsets in the reference's order, for the batched paths
exact.py           the same terms batched with the reference's floating-point path (default mode)
fast.py            pi through the window's Gram matrix (mode "fast"): the candidate loop and the window's choice
fast_terms.py      C and eq. (5) through the Gram matrix on lanes, shared by both pi definitions
fast_reference.py  reference pi in fast mode: LAPACK's eigen-pairs and the rounding probes
fast_canonical.py  canonical pi in fast mode: up to 32 candidates decomposed and put in canonical form together
eigen.py           the compiled eigensolver of canonical pi (Householder + QL, many matrices at a time)
canonical.py       the canonical form of eigen-pairs (pi independent of the solver) and its rounding bound
decision.py        the winner, and whether rounding could change it (ambiguous windows)
warm.py            compiles the numba kernels in a background process ahead of a long job
See docs/msa.md.
"""

from msa_slam._lazy import lazy_exports

_EXPORTS = {
    "MODES": "params",
    "MSAParams": "params",
    "MSASampler": "sampler",
    "ScoreWeights": "terms",
    "WindowResult": "terms",
    "optimise_window": "window",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
