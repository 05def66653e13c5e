"""An experiment cell's row: the columns of results.csv and results.md, one typed row per cell (finished or failed),
read by the grid's tables and figures and by `reproduce`'s tables and claims."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field

from msa_slam.evaluation.run_metrics import TableRow

COLUMNS = (
    "cell",
    "pipeline",
    "dataset",
    "descriptor",
    "method",
    "sampler",
    "seed",
    "parameters",
    "frames",
    "keyframes",
    "candidates",
    "verified",
    "false_loops",
    "ate_before_m",
    "ate_after_m",
    "improvement_t_pct",
    "improvement_r_pct",
    "rpe_pct",
    "rpe_10m_m",
    "kf_ate_before_m",
    "kf_ate_after_m",
    "kf_improvement_t_pct",
    "pr_auc",
    "f1_max",
    "memory_mib",
    "memory_vs_reference_pct",
    "bytes_per_keyframe",
    "time_s",
    "fps",
    "backend_fps",
    "backend_p99_ms",
    "process_peak_rss_mib",
    "rss_growth_mib",
    "rejected",
    "unavailable",
)
METRICS = COLUMNS[COLUMNS.index("frames") : COLUMNS.index("unavailable")]  # a row's metric columns


@dataclass(frozen=True)
class CellRow:
    """One cell of a grid as results.csv and results.md show it: what ran, its metric columns (METRICS, None when
    n/a, `reasons` saying why) and, for the paper's tables and sweeps (reproduce), its `mode` and `swept` values."""

    cell: str
    pipeline: str
    dataset: str
    descriptor: str
    method: str
    sampler: str
    seed: int
    parameters: str  # the grid parameters as JSON, "" for none
    values: Mapping[str, float | None]
    reasons: Mapping[str, str] = field(default_factory=dict)
    mode: str = ""  # oracle or realistic
    swept: Mapping[str, float] = field(default_factory=dict)  # a sweep's parameter: value

    def value(self, column: str) -> float | None:
        """The metric `column` (one of METRICS), None when n/a."""
        return self.values[column]

    def record(self) -> TableRow:
        """The row as results.csv holds it (COLUMNS; `unavailable`: the reasons as JSON)."""
        return {
            "cell": self.cell,
            "pipeline": self.pipeline,
            "dataset": self.dataset,
            "descriptor": self.descriptor,
            "method": self.method,
            "sampler": self.sampler,
            "seed": self.seed,
            "parameters": self.parameters,
            **{column: self.values[column] for column in METRICS},
            "unavailable": json.dumps(dict(self.reasons), sort_keys=True) if self.reasons else "",
        }
