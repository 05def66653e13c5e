"""The rules that turn measured numbers into a claim's verdict: holds, does not hold, or not separable.

A difference counts only when it exceeds the seed-to-seed spread: the paired t-test of
msa_slam.evaluation.spread over runs that share a world (same dataset and seed) at alpha 0.05, or, for a
threshold claim, the mean +- sample std lying wholly on one side of the threshold. Everything else is "not
separable", never a verdict either way. The rules are fixed here, before any run: no setting is tuned so that a
claim holds, and a claim that does not hold is reported as not holding.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from msa_slam.evaluation.spread import MIN_SEEDS, PairedVerdict, paired_verdict

HOLDS, FAILS, NOT_SEPARABLE = "holds", "does not hold", "not separable"


def difference(a: Sequence[float], b: Sequence[float]) -> PairedVerdict:
    """Paired comparison of a against b (same length, pair i shares its world; higher is +1): separable when the
    paired t-test gives p < 0.05, or with at least MIN_SEEDS pairs all differing by the same non-zero amount (no
    spread); values that differ only by rounding are equal (spread.without_rounding)."""
    if len(a) != len(b):
        raise ValueError(f"paired values of unequal length ({len(a)} and {len(b)})")
    return paired_verdict(list(a), list(b), True, list(range(len(a))), unit="pair")


def mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample std (0 for a single value) of `values`."""
    arr = np.asarray(values, dtype=float)
    return float(arr.mean()), float(arr.std(ddof=1)) if len(arr) > 1 else 0.0


def within(values: Sequence[float], low: float, high: float) -> str:
    """A threshold claim "the value lies in [low, high]": holds when the mean does, does not hold when mean +- std
    lies wholly outside, not separable when the spread reaches into the band."""
    if not len(values):
        return NOT_SEPARABLE
    mean, std = mean_std(values)
    if low <= mean <= high:
        return HOLDS
    return FAILS if mean + std < low or mean - std > high else NOT_SEPARABLE


def above(values: Sequence[float], limit: float) -> str:
    """A threshold claim "the value exceeds `limit`": mean - std above it holds, mean + std below it does not."""
    if not len(values):
        return NOT_SEPARABLE
    mean, std = mean_std(values)
    if mean - std > limit:
        return HOLDS
    return FAILS if mean + std < limit else NOT_SEPARABLE


def combine(*verdicts: str) -> str:
    """A claim of several parts: it does not hold when one part does not, else is not separable when one part is."""
    if FAILS in verdicts:
        return FAILS
    return NOT_SEPARABLE if NOT_SEPARABLE in verdicts else HOLDS


def expect(found: PairedVerdict, sign: int) -> str:
    """A part claiming a difference of `sign` (+1 greater, -1 smaller): holds when found so, does not hold when
    found the other way, not separable when no difference is."""
    if found.sign == 0:
        return NOT_SEPARABLE
    return HOLDS if found.sign == sign else FAILS


def not_worse(found: PairedVerdict) -> str:
    """A part claiming a is kept at b's level ("keeps the accuracy"): does not hold when a is separably smaller;
    not separable when no test is possible (fewer than MIN_SEEDS pairs); holds otherwise."""
    if found.sign < 0:
        return FAILS
    return NOT_SEPARABLE if found.pairs < MIN_SEEDS else HOLDS


def stable_and_sensitive(accuracy: PairedVerdict, memory: PairedVerdict) -> str:
    """The distance-bound claim: accuracy stable (its largest difference between settings not separable) and
    memory sensitive (the memory at the sweep's two ends separable)."""
    if accuracy.pairs < MIN_SEEDS or memory.pairs < MIN_SEEDS:
        return NOT_SEPARABLE
    if accuracy.sign != 0:
        return FAILS
    return HOLDS if memory.sign != 0 else NOT_SEPARABLE


def no_universal(scenarios: Mapping[str, Mapping[str, Sequence[float]]]) -> tuple[str, dict[str, list[str]]]:
    """ "No constant interval suits every scenario" from each scenario's accuracy per constant (paired over the
    scenario's seeds; higher is better). A constant is beaten in a scenario when the best one there (by mean) is
    separably better. Holds when every constant is beaten somewhere; does not hold when one constant is the best
    by mean in every scenario; otherwise not separable. Returns the verdict and where each constant was beaten."""
    beaten: dict[str, list[str]] = {}
    best_of: dict[str, str] = {}
    for scenario, constants in scenarios.items():
        best = max(constants, key=lambda c: float(np.mean(constants[c])))
        best_of[scenario] = best
        for constant, values in constants.items():
            beaten.setdefault(constant, [])
            if constant != best and difference(constants[best], values).sign > 0:
                beaten[constant].append(scenario)
    if not beaten:
        return NOT_SEPARABLE, beaten
    if all(beaten[c] for c in beaten):
        return HOLDS, beaten
    if len(set(best_of.values())) == 1 and len(best_of) > 1:
        return FAILS, beaten
    return NOT_SEPARABLE, beaten


def extrapolate(distance_m: ArrayLike, memory: ArrayLike, target_m: float) -> float:
    """The memory at `target_m` of path from its measured growth: a least-squares line through the second half
    of the run (past the warm-up, where growth is steady), evaluated at the target."""
    d, m = np.asarray(distance_m, dtype=float), np.asarray(memory, dtype=float)
    if len(d) < 4 or d[-1] <= d[len(d) // 2]:
        raise ValueError("too short a run to measure memory growth (fewer than 4 steps, or no travel)")
    half = slice(len(d) // 2, None)
    slope, intercept = np.polyfit(d[half], m[half], 1)
    return float(slope * target_m + intercept)
