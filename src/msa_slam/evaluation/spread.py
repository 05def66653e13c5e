"""Repetitions over world seeds: mean, spread, per-seed ranks and whether a difference exceeds the spread.

One simulated world decides nothing (changing only KITTI-05's world seed moved every sampler's
improvement from ~37 % to ~72 % and MSA's rank from 3 to 7). So each metric is reported as mean and sample
standard deviation (ddof 1) over seeds, with the rank of every method on each seed, and MSA is compared to
each baseline with a paired test over seeds (PAIRED_TEST): the pairs share a world, so the world's effect
cancels out and only the samplers' difference is tested against its own seed-to-seed variation.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

MIN_SEEDS = 3  # fewer pairs leave the spread of the differences undetermined (1 degree of freedom or none)
ALPHA = 0.05
# Per-seed differences within this fraction of the values' scale (at least 1) are rounding, not a result:
# on a sequence where no sampler closes a loop the improvements are +-1e-11 % and a t-test would rank noise.
ROUNDING = 1e-9
PAIRED_TEST = "paired t-test (scipy.stats.ttest_rel, two-sided, alpha 0.05)"
PAIRED_TEST_WHY = (
    "a paired t-test rather than Wilcoxon's signed-rank test: with n seeds the exact two-sided "
    "Wilcoxon p-value cannot go below 2/2^n (0.25 for 3 seeds, 0.0625 for 5), so with the few "
    "seeds a comparison affords it could never find a difference; the t-test can, assuming the "
    "per-seed differences are roughly normal"
)
REFERENCE = "msa"


@dataclass(frozen=True)
class Spread:
    """A metric of one method over seeds: the per-seed values (None where unavailable), mean and std of the
    available ones (std None with fewer than 2) and the method's rank on each seed (1 = best)."""

    values: list[float | None]
    mean: float | None
    std: float | None
    ranks: list[int | None]


def seed_ranks(
    values: Mapping[str, float | None], higher_is_better: bool, spec: str | None = None
) -> dict[str, int | None]:
    """Rank of each method on one seed (1 = best; None for unavailable values). Values equal once formatted
    with `spec` (the metric's display format, evaluation.display.spec_for; None: as they are) are ties and
    share the best of their ranks ("min": 1, 1, 3), so a PR-AUC of 0.9999999999999999 is not behind 1.0 and
    ATEs 3e-9 m apart do not rank 1 and 2 when the tables show them as equal."""
    known = {
        m: v if spec is None else float(format(v, spec))
        for m, v in values.items()
        if v is not None and not math.isnan(v)
    }
    if not known:
        return dict.fromkeys(values)
    signed = np.array([-v if higher_is_better else v for v in known.values()])
    ranked = dict(zip(known, stats.rankdata(signed, method="min").astype(int).tolist()))
    return {m: ranked.get(m) for m in values}


def spreads(
    per_seed: Sequence[Mapping[str, float | None]], higher_is_better: bool | None, spec: str | None = None
) -> dict[str, Spread]:
    """Spread of every method of `per_seed` (one mapping method -> value per seed); ranks only when the
    metric has a direction (`higher_is_better` not None), at the display format `spec` (seed_ranks)."""
    methods = list(dict.fromkeys(m for seed in per_seed for m in seed))
    ranks = [
        seed_ranks({m: seed.get(m) for m in methods}, higher_is_better, spec)
        if higher_is_better is not None
        else dict.fromkeys(methods)
        for seed in per_seed
    ]
    out = {}
    for m in methods:
        values = [seed.get(m) for seed in per_seed]
        known = [v for v in values if v is not None and not math.isnan(v)]
        mean = float(np.mean(known)) if known else None
        std = float(np.std(known, ddof=1)) if len(known) >= 2 else None
        out[m] = Spread(values, mean, std, [r[m] for r in ranks])
    return out


def without_rounding(a: float, b: float) -> float:
    """a - b, or 0.0 when the two differ only by floating-point rounding (within ROUNDING of their scale, at least
    1): a report then shows them as equal instead of a difference of 1e-12 that means nothing."""
    difference = a - b
    return 0.0 if abs(difference) <= ROUNDING * max(1.0, abs(a), abs(b)) else difference


@dataclass(frozen=True)
class PairedVerdict:
    """The paired test of a reference method (MSA) against one baseline over seeds that share a world
    (PAIRED_TEST): the per-pair differences reference - baseline (rounding shown as 0.0: without_rounding), their
    mean and sample std, the p-value, and `sign`: +1 the reference better beyond the seed spread, -1 worse, 0 no
    separable difference. `na` says why there is no p-value (None when there is one)."""

    pairs: int
    mean_difference: float | None
    std_difference: float | None
    p: float | None
    sign: int
    na: str | None

    @property
    def verdict(self) -> str:
        """One phrase: "better, beyond the seed spread (p=0.012)", "within the seed spread (p=0.4)", or n/a's
        reason."""
        if self.p is None:
            return self.na or "n/a"
        shown = "p<0.001" if self.p < 0.001 else f"p={self.p:.3f}"  # a p-value is never 0
        if self.sign == 0:
            return f"within the seed spread ({shown})"
        return f"{'better' if self.sign > 0 else 'worse'}, beyond the seed spread ({shown})"

    def text(self) -> str:
        """ "mean difference +1.2 ± 0.3 over 3 pair(s), p=0.012", or with why there is no p-value."""
        mean = "n/a" if self.mean_difference is None else _number(self.mean_difference, signed=True)
        std = "" if self.std_difference is None else f" ± {_number(self.std_difference)}"
        if self.p is not None:
            p = "p<0.001" if self.p < 0.001 else f"p={self.p:.3f}"
        else:
            p = f"p n/a ({(self.na or 'n/a').removeprefix('n/a: ')})"
        return f"mean difference {mean}{std} over {self.pairs} pair(s), {p}"

    def to_json(self) -> dict[str, object]:
        """The verdict as seeds.json records it."""
        return {
            "p": self.p,
            "mean_difference": self.mean_difference,
            "std_difference": self.std_difference,
            "pairs": self.pairs,
            "verdict": self.verdict,
        }


def _number(x: float, signed: bool = False) -> str:
    """Three significant digits; an exact zero (rounding removed: without_rounding) as 0.0."""
    return "0.0" if x == 0 else f"{x:+.3g}" if signed else f"{x:.3g}"


def paired_verdict(
    reference: Sequence[float | None],
    baseline: Sequence[float | None],
    higher_is_better: bool,
    seeds: Sequence[int],
    unit: str = "seed",
) -> PairedVerdict:
    """Whether the per-seed difference reference - baseline exceeds its seed-to-seed spread (PAIRED_TEST). No
    p-value, with the reason, when a value is n/a, with fewer than MIN_SEEDS pairs, when the values differ only
    by rounding, or when the difference is the same on every seed (no variance: the t statistic is undefined;
    then `sign` still says which side, since every seed agrees). `unit` names a pair in the reasons (a seed, or
    a pair of runs on one world when they pool datasets)."""
    missing = [
        s for s, a, b in zip(seeds, reference, baseline) if a is None or b is None or math.isnan(a) or math.isnan(b)
    ]
    if missing:
        return PairedVerdict(
            len(seeds),
            None,
            None,
            None,
            0,
            f"n/a: a value is n/a on {unit}(s) {', '.join(map(str, missing))} (that seed's notes say why)",
        )
    diff = np.array(
        [without_rounding(a, b) for a, b in zip(reference, baseline) if a is not None and b is not None],
        dtype=np.float64,
    )
    mean = float(diff.mean()) if len(diff) else None
    std = float(diff.std(ddof=1)) if len(diff) >= 2 else None
    if len(seeds) < MIN_SEEDS:
        return PairedVerdict(
            len(seeds), mean, std, None, 0, f"n/a: {len(seeds)} {unit}(s), the paired test needs at least {MIN_SEEDS}"
        )
    if not diff.any():  # equal, or e.g. no loop closed: the optimiser only rounded
        return PairedVerdict(len(seeds), 0.0, 0.0, None, 0, f"no difference on any {unit}")
    better = 1 if (float(diff.mean()) > 0) == higher_is_better else -1
    if np.all(diff == diff[0]):  # zero variance: the t statistic is undefined
        return PairedVerdict(
            len(seeds),
            mean,
            0.0,
            None,
            better,
            f"{'better' if better > 0 else 'worse'} by the same amount on every {unit} (no variance: no p-value)",
        )
    with warnings.catch_warnings():  # scipy's "nearly identical data" warning: the p-value then says as much
        warnings.simplefilter("ignore", RuntimeWarning)
        p = float(stats.ttest_1samp(diff, 0.0).pvalue)  # = ttest_rel(reference, baseline), rounding left out
    return PairedVerdict(len(seeds), mean, std, p, better if p < ALPHA else 0, None)
