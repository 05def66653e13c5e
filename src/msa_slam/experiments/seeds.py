"""`compare --seeds`: the comparison repeated over simulated worlds, summarised per metric as mean +- std,
per-seed ranks and, for MSA against each baseline, whether the difference exceeds the seed-to-seed spread
(msa_slam.evaluation.spread)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

from msa_slam.errors import InputError
from msa_slam.evaluation import NA, fmt
from msa_slam.evaluation.display import spec_for
from msa_slam.evaluation.run_metrics import TableRow
from msa_slam.evaluation.spread import (
    MIN_SEEDS,
    PAIRED_TEST,
    PAIRED_TEST_WHY,
    REFERENCE,
    PairedVerdict,
    Spread,
    paired_verdict,
    spreads,
)
from msa_slam.sources.spec import spec_kind

# comparison column -> (label, higher is better; None: no direction, no rank and no test)
SEED_METRICS: dict[str, tuple[str, bool | None]] = {
    "improvement_t_pct": ("t. ATE impr. [%]", True),
    "improvement_r_pct": ("R. ATE impr. [%]", True),
    "ate_after_m": ("ATE after [m]", False),
    "rpe_pct": ("RPE KITTI segments [%]", False),  # lengths: each seed's comparison.md
    "rpe_10m_m": ("RPE 10 m all-pairs mean [m]", False),
    "pr_auc": ("PR-AUC", True),
    "f1_max": ("F1-max", True),
    "false_loops": ("false loops", False),
    "memory_mib": ("memory [MiB]", False),
    "rss_growth_mib": ("RSS growth [MiB]", False),
    "keyframes": ("keyframes", None),
    "verified": ("loops", None),
    "rejected": ("rejected", None),
}


def parse_seeds(text: str) -> list[int]:
    """World seeds from "0,1,2": distinct non-negative integers."""
    try:
        seeds = [int(item) for item in text.split(",") if item.strip()]
    except ValueError:
        raise InputError(f"--seeds {text!r}: expected comma-separated non-negative integers, e.g. 0,1,2") from None
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise InputError(f"--seeds {text!r}: expected distinct non-negative integers, e.g. 0,1,2")
    return seeds


def seeded_datasets(dataset: str, seeds: Sequence[int]) -> list[str]:
    """The `sim:` spec of each world seed; only simulated data has a world seed."""
    from msa_slam.sources import parse_spec

    if spec_kind(dataset) != "sim":
        raise InputError(
            f"--seeds: dataset {dataset!r} is not simulated; world seeds exist only for sim: "
            "datasets (e.g. --dataset sim:test --seeds 0,1,2)"
        )
    if "seed" in parse_spec(dataset).keys:
        raise InputError(f"--seeds: dataset {dataset!r} already sets seed=; give the seeds with --seeds only")
    return [f"{dataset},seed={s}" for s in seeds]


@dataclass(frozen=True)
class SeedMetric:
    """One metric over the seeds: each method's spread and, for a metric with a direction, MSA's verdict against
    each baseline (evaluation.spread.paired_verdict)."""

    label: str
    higher_is_better: bool | None
    methods: dict[str, Spread]
    msa_vs: dict[str, PairedVerdict]


@dataclass(frozen=True)
class SeedSummary:
    """The spread over seeds (seeds.json): per comparison column (SEED_METRICS), and the paired test used."""

    seeds: list[int]
    metrics: dict[str, SeedMetric]

    def to_json(self) -> dict[str, object]:
        """seeds.json."""
        return {
            "seeds": self.seeds,
            "test": PAIRED_TEST,
            "test_choice": PAIRED_TEST_WHY,
            "min_seeds": MIN_SEEDS,
            "metrics": {
                column: {
                    "label": e.label,
                    "higher_is_better": e.higher_is_better,
                    "methods": {m: vars(sp) for m, sp in e.methods.items()},
                    "msa_vs": {m: pv.to_json() for m, pv in e.msa_vs.items()},
                }
                for column, e in self.metrics.items()
            },
        }


class MethodValues(Protocol):
    """A method's row of one seed: compare's (evaluation.run_metrics.ComparisonRow) or a grid cell's
    (experiments.rows.CellRow), each with every SEED_METRICS column."""

    @property
    def method(self) -> str: ...

    def value(self, column: str) -> float | None: ...


def seed_summary(rows: Mapping[int, Sequence[MethodValues]]) -> SeedSummary:
    """Per metric: each method's values, mean, std and ranks over the seeds (`rows`: seed -> its methods' rows),
    and MSA's verdict against each baseline."""
    seeds = list(rows)
    methods = list(dict.fromkeys(r.method for seed_rows in rows.values() for r in seed_rows))
    per_seed = {s: {r.method: r for r in rows[s]} for s in seeds}
    metrics: dict[str, SeedMetric] = {}
    for column, (label, higher) in SEED_METRICS.items():
        values = [{m: _value(per_seed[s].get(m), column) for m in methods} for s in seeds]
        spread = spreads(values, higher, spec_for(column))  # ranks as the tables show the values
        verdicts = {}
        if higher is not None and REFERENCE in spread:
            for m in methods:
                if m != REFERENCE:
                    verdicts[m] = paired_verdict(spread[REFERENCE].values, spread[m].values, higher, seeds)
        metrics[column] = SeedMetric(label, higher, spread, verdicts)
    return SeedSummary(seeds, metrics)


def _value(row: MethodValues | None, column: str) -> float | None:
    """A method's value in one seed's row; None where the method did not finish on that seed or the value is n/a."""
    value = None if row is None else row.value(column)
    return None if value is None else float(value)


def _cell(column: str, spread: Spread) -> str:
    """mean ± std with the column's decimals (evaluation.display.spec_for); a value known on one seed only is
    shown alone, marked (SEED_NOTES says why)."""
    if spread.mean is None:
        return NA + "¹"
    digits = spec_for(column)
    if spread.std is None:
        return f"{fmt(spread.mean, digits)}²"
    return f"{fmt(spread.mean, digits)} ± {fmt(spread.std, digits)}"


# Why a cell of the seed tables holds no (full) figure: the seeds' own reports give each value's reason.
SEED_NOTES = [
    "¹ n/a: the value is n/a on every seed (each seed's report under seeds/seed-<n>/ says why).",
    "² known on one seed only: no spread over seeds.",
    "Ranks: n/a where that seed has no value for the method.",
]


def seed_markdown(summary: SeedSummary) -> str:
    """Three tables: mean ± std per method and metric, the per-seed ranks, MSA's paired-test verdicts."""
    metrics, seeds = summary.metrics, summary.seeds
    methods = list(next(iter(metrics.values())).methods)
    labels = [e.label for e in metrics.values()]
    lines = [
        f"Seeds {', '.join(map(str, seeds))}: mean ± sample std (ddof 1) over the seeds.",
        "",
        "| method | " + " | ".join(labels) + " |",
        "|" + "---|" * (len(labels) + 1),
    ]
    cells = [[_cell(k, e.methods[m]) for k, e in metrics.items()] for m in methods]
    lines += [f"| {m} | " + " | ".join(row) + " |" for m, row in zip(methods, cells)]
    marks = [note for mark, note in zip("¹²", SEED_NOTES) if any(c.endswith(mark) for row in cells for c in row)]
    lines += ["", *marks] if marks else []
    ranked = {k: e for k, e in metrics.items() if e.higher_is_better is not None}
    lines += [
        "",
        "Rank per seed (1 = best, among the methods with a value; seeds " + ", ".join(map(str, seeds)) + "):",
        "",
        "| method | " + " | ".join(e.label for e in ranked.values()) + " |",
        "|" + "---|" * (len(ranked) + 1),
    ]
    lines += [
        f"| {m} | "
        + " | ".join(", ".join(NA if r is None else str(r) for r in e.methods[m].ranks) for e in ranked.values())
        + " |"
        for m in methods
    ]
    if any(r is None for e in ranked.values() for m in methods for r in e.methods[m].ranks):
        lines += ["", SEED_NOTES[2]]
    baselines = [m for m in methods if m != REFERENCE]
    if any(e.msa_vs for e in ranked.values()):
        lines += [
            "",
            f"MSA against each baseline, {PAIRED_TEST} over the seeds: does the difference exceed "
            f"the seed-to-seed spread? ({PAIRED_TEST_WHY}.)",
            "",
            "| baseline | " + " | ".join(e.label for e in ranked.values()) + " |",
            "|" + "---|" * (len(ranked) + 1),
        ]
        lines += [
            f"| {b} | " + " | ".join(e.msa_vs[b].verdict if b in e.msa_vs else NA for e in ranked.values()) + " |"
            for b in baselines
        ]
    else:
        lines += ["", f"No paired test: no method labelled {REFERENCE!r} in the comparison."]
    return "\n".join(lines) + "\n"


def seed_rows(summary: SeedSummary) -> list[TableRow]:
    """seeds.csv rows: one per method and metric (mean, std, per-seed values and ranks, MSA's verdict)."""
    out: list[TableRow] = []
    for column, entry in summary.metrics.items():
        for method, sp in entry.methods.items():
            verdict = entry.msa_vs.get(method)  # none against itself, nor for a metric without a direction
            out.append(
                {
                    "metric": column,
                    "method": method,
                    "mean": sp.mean,
                    "std": sp.std,
                    "values": " ".join(NA if v is None else f"{v:.6g}" for v in sp.values),
                    "ranks": " ".join(NA if r is None else str(r) for r in sp.ranks),
                    "msa_vs_p": None if verdict is None else verdict.p,
                    "msa_vs_verdict": "" if verdict is None else verdict.verdict,
                }
            )
    return out


SEED_COLUMNS = ("metric", "method", "mean", "std", "values", "ranks", "msa_vs_p", "msa_vs_verdict")
