"""Repetitions over world seeds: mean, spread, per-seed ranks and whether a difference exceeds the spread.

One simulated world decides nothing (changing only KITTI-05's world seed moved every sampler's
improvement from ~37 % to ~72 % and MSA's rank from 3 to 7). So each metric is reported as mean and sample
standard deviation (ddof 1) over seeds, with the rank of every method on each seed, and MSA is compared to
each baseline with a paired test over seeds (PAIRED_TEST): the pairs share a world, so the world's effect
cancels out and only the samplers' difference is tested against its own seed-to-seed variation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy import stats

MIN_SEEDS = 3  # fewer pairs leave the spread of the differences undetermined (1 degree of freedom or none)
ALPHA = 0.05
# Per-seed differences within this fraction of the values' scale (at least 1) are rounding, not a result:
# on a sequence where no sampler closes a loop the improvements are +-1e-11 % and a t-test would rank noise.
ROUNDING = 1e-9
PAIRED_TEST = "paired t-test (scipy.stats.ttest_rel, two-sided, alpha 0.05)"
PAIRED_TEST_WHY = ("a paired t-test rather than Wilcoxon's signed-rank test: with n seeds the exact two-sided "
                   "Wilcoxon p-value cannot go below 2/2^n (0.25 for 3 seeds, 0.0625 for 5), so with the few "
                   "seeds a comparison affords it could never find a difference; the t-test can, assuming the "
                   "per-seed differences are roughly normal")
REFERENCE = "msa"


@dataclass(frozen=True)
class Spread:
    """A metric of one method over seeds: the per-seed values (None where unavailable), mean and std of the
    available ones (std None with fewer than 2) and the method's rank on each seed (1 = best)."""

    values: list[float | None]
    mean: float | None
    std: float | None
    ranks: list[int | None]


def seed_ranks(values: Mapping[str, float | None], higher_is_better: bool, spec: str | None = None
               ) -> dict[str, int | None]:
    """Rank of each method on one seed (1 = best; None for unavailable values). Values equal once formatted
    with `spec` (the metric's display format, evaluation.display.spec_for; None: as they are) are ties and
    share the best of their ranks ("min": 1, 1, 3), so a PR-AUC of 0.9999999999999999 is not behind 1.0 and
    ATEs 3e-9 m apart do not rank 1 and 2 when the tables show them as equal."""
    known = {m: v if spec is None else float(format(v, spec)) for m, v in values.items()
             if v is not None and not math.isnan(v)}
    if not known:
        return dict.fromkeys(values)
    signed = np.array([-v if higher_is_better else v for v in known.values()])
    ranked = dict(zip(known, stats.rankdata(signed, method="min").astype(int).tolist()))
    return {m: ranked.get(m) for m in values}


def spreads(per_seed: Sequence[Mapping[str, float | None]], higher_is_better: bool | None, spec: str | None = None
            ) -> dict[str, Spread]:
    """Spread of every method of `per_seed` (one mapping method -> value per seed); ranks only when the
    metric has a direction (`higher_is_better` not None), at the display format `spec` (seed_ranks)."""
    methods = list(dict.fromkeys(m for seed in per_seed for m in seed))
    ranks = [seed_ranks({m: seed.get(m) for m in methods}, higher_is_better, spec) if higher_is_better is not None
             else dict.fromkeys(methods) for seed in per_seed]
    out = {}
    for m in methods:
        values = [seed.get(m) for seed in per_seed]
        known = [v for v in values if v is not None and not math.isnan(v)]
        mean = float(np.mean(known)) if known else None
        std = float(np.std(known, ddof=1)) if len(known) >= 2 else None
        out[m] = Spread(values, mean, std, [r[m] for r in ranks])
    return out


def paired_verdict(reference: Sequence[float | None], baseline: Sequence[float | None],
                   higher_is_better: bool, seeds: Sequence[int]) -> dict[str, object]:
    """Whether the per-seed difference reference - baseline exceeds its seed-to-seed spread (PAIRED_TEST):
    {"p": p-value or None, "mean_difference": ..., "verdict": one phrase}."""
    missing = [s for s, a, b in zip(seeds, reference, baseline) if a is None or b is None
               or math.isnan(a) or math.isnan(b)]
    if missing:
        return {"p": None, "mean_difference": None, "verdict": f"n/a: a value is n/a on seed(s) "
                f"{', '.join(map(str, missing))} (that seed's notes say why)"}
    if len(seeds) < MIN_SEEDS:
        return {"p": None, "mean_difference": None,
                "verdict": f"n/a: {len(seeds)} seed(s), the paired test needs at least {MIN_SEEDS}"}
    ref, base = np.asarray(reference, dtype=np.float64), np.asarray(baseline, dtype=np.float64)
    diff = ref - base
    mean = float(diff.mean())
    better = (mean > 0) == higher_is_better
    scale = max(1.0, float(np.abs(np.concatenate([ref, base])).max()))
    if np.all(np.abs(diff) <= ROUNDING * scale):  # equal, or e.g. no loop closed: the optimiser only rounded
        return {"p": None, "mean_difference": mean, "verdict": "no difference on any seed"}
    if np.all(diff == diff[0]):  # no spread at all: the t statistic is undefined
        return {"p": None, "mean_difference": mean,
                "verdict": f"{'better' if better else 'worse'} by the same amount on every seed"}
    p = float(stats.ttest_rel(ref, base).pvalue)
    shown = "p<0.001" if p < 0.001 else f"p={p:.3f}"  # a p-value is never 0
    verdict = (f"{'better' if better else 'worse'}, beyond the seed spread ({shown})" if p < ALPHA
               else f"within the seed spread ({shown})")
    return {"p": p, "mean_difference": mean, "verdict": verdict}
