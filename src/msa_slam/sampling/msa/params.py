"""MSA's parameters (paper section IV): the window, the score's weights, the distance bounds, the ablations and
the computation's mode, with the limit on the window's power set checked with them."""

from __future__ import annotations

from typing import Literal, get_args

from pydantic import Field, model_validator

from msa_slam.sampling.params import Boolean, Integer, Real, SamplerParams, rule

Mode = Literal["exact", "fast"]
PiDefinition = Literal["reference", "canonical"]  # LAPACK's eigenvectors as they come, or canonical.py's
MODES: tuple[str, ...] = get_args(Mode)
PI_DEFINITIONS: tuple[str, ...] = get_args(PiDefinition)
MAX_CANDIDATES = 2**15 - 2  # per window optimisation, i.e. N <= 16: measured 5 s a window in exact mode
# (sc20x60, 17811 feasible candidates), 1 s in fast mode; N = 20 took 116 s for 150 frames, N = 30 runs out of memory
MAX_CANDIDATES_CANONICAL = 2**19 - 2  # N <= 20 with pi="canonical" in fast mode: compiled solver on 2 threads,
# candidates streamed (benchmarks/bench_msa.py)


def candidate_count_problem(window: int, neighbours: int, mode: str = "exact", pi: str = "reference") -> str | None:
    """Why a window's power set is too large to enumerate (time, then memory, explode), or None.

    A window optimisation scores every subset that starts with the window's first member: 2^(n-1) - 2
    candidates for n members, and n reaches window + max(neighbours - 1, 0) (old keyframes join a full window,
    the nearest one left out as the reference does).
    Canonical pi on the fast path goes to n = 20; the other combinations stay at 16.
    """
    members = window + max(neighbours - 1, 0)
    canonical_fast = mode == "fast" and pi == "canonical"
    limit, largest = (MAX_CANDIDATES_CANONICAL, 20) if canonical_fast else (MAX_CANDIDATES, 16)
    if 2 ** min(members - 1, 64) - 2 <= limit:
        return None
    count = f"{2 ** (members - 1) - 2}" if members <= 64 else f"about 10^{int((members - 1) * 0.30103)}"
    joined = f" (+{neighbours - 1} neighbour{'s' * (neighbours > 2)})" if neighbours > 1 else ""
    return (
        f"window={window}{joined}: up to 2^{members - 1} - 2 = {count} candidates per window optimisation, "
        f"more than the limit of {limit} (window + max(neighbours - 1, 0) <= {largest}"
        + ("" if canonical_fast else "; up to 20 with mode='fast', pi='canonical'")
        + ")"
    )


class MSAParams(SamplerParams):
    """MSA's parameters (sampling/msa/sampler.py, docs/msa.md) and the standstill gate."""

    NAME = "msa"

    sampler: Literal["msa"] = "msa"
    window: Integer = Field(10, ge=3, description="N, the frames of one window optimisation")
    alpha: Real = Field(1.0, gt=0, description="alpha of the score (alpha + rho) / (beta + pi), eq. (8)")
    beta: Real = Field(1.0, gt=0, description="beta of the score, eq. (8)")
    lambda_l: Real = Field(0.1, ge=0, description="lower distance bound, a multiple of the mean step (eq. 7)")
    lambda_u: Real = Field(3.0, gt=0, description="upper distance bound, a multiple of the mean step (eq. 7)")
    neighbours: Integer = Field(0, ge=0, description="old keyframes near the window's end that join it at revisits")
    use_rho: Boolean = Field(True, description="the score's rho term (off: the paper's ablation)")
    use_pi: Boolean = Field(True, description="the score's pi term (off: the paper's ablation)")
    mode: Mode = Field("exact", description="exact: the reference's floating-point path; fast: the Gram matrix")
    pi: PiDefinition = Field(
        "reference",
        description="reference: LAPACK's eigenvectors (the authors' keyframes); "
        "canonical: the same keyframes on every machine",
    )

    @model_validator(mode="after")
    def _bounds_and_size(self) -> MSAParams:
        """The bounds must be ordered; the window's power set must be small enough to enumerate."""
        if self.lambda_l > self.lambda_u:
            raise rule(
                f"lambda_l={self.lambda_l!r} > lambda_u={self.lambda_u!r} is not allowed; expected lambda_l <= lambda_u"
            )
        problem = candidate_count_problem(self.window, self.neighbours, self.mode, self.pi)
        if problem is not None:
            raise rule(problem)
        return self
