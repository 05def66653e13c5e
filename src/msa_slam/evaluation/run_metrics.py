"""The report of one run (batch or online) as one immutable object, and the table rows made from it: compare's
Table-I row and an experiment cell's values, each value a number or `Unavailable` with its reason.

Sections (evaluation.metrics): what was run, loops, keyframe and full-rate trajectory error, place recognition,
memory, time, settings and, online, throughput. metrics.json is `evaluation.metrics_writer.to_json` of it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from msa_slam.evaluation.metrics import (
    ONLINE,
    FullRateTrajectory,
    JSONValue,
    KeyframeTrajectory,
    Loops,
    Memory,
    PlaceRecognition,
    ReferencePR,
    RunIdentity,
    RunSetup,
    Throughput,
    Timing,
    Unavailable,
    Value,
    known,
)

TableRow = dict[str, object]  # one row of a table (compare's, an experiment's): column -> value, None when n/a
BATCH_UNTIMED = (
    "the batch pipeline (Table I protocol) optimises the whole sequence at once, so it has no per-frame "
    "throughput or latency (an online grid measures them)"
)


@dataclass(frozen=True)
class ComparisonRow:
    """compare's Table-I row of one method: its values by column (reporting.comparison.COLUMNS after `method`),
    None when n/a (the report's notes say why)."""

    method: str
    values: Mapping[str, float | None]

    def value(self, column: str) -> float | None:
        """The value of `column`, None when n/a."""
        return self.values[column]

    def record(self) -> TableRow:
        """The row as comparison.csv and comparison.md hold it."""
        return {"method": self.method, **self.values}


@dataclass(frozen=True)
class Stamp:
    """What metrics.json adds to the measured report: the writing version and the keyframes' frames."""

    version: str
    keyframe_frames: tuple[int, ...]


@dataclass(frozen=True)
class RunMetrics:
    """The whole report of one run; `reasons`: metric -> why it is unavailable, in the order they were found
    (metrics.json `unavailable`, which names groups of values: "ate", "pr", ...); `throughput` None for a batch
    run; `stamp` None until the report is written to (or read from) metrics.json."""

    pipeline: str
    run: RunIdentity
    loops: Loops
    keyframe_trajectory: KeyframeTrajectory
    full_rate: FullRateTrajectory
    reasons: Mapping[str, str]
    warnings: tuple[str, ...]
    place_recognition: PlaceRecognition
    memory: Memory
    sampler_stats: Mapping[str, JSONValue]
    timing: Timing
    setup: RunSetup
    throughput: Throughput | None = None
    stamp: Stamp | None = None

    @property
    def online(self) -> bool:
        return self.pipeline == ONLINE

    @property
    def method(self) -> str:
        return self.run.method

    def per_frame(self, figure: str) -> Value:
        """An online run's throughput `figure` (fps, backend_fps, backend_p99_ms); unavailable for a batch run."""
        if self.throughput is None:
            return Unavailable(BATCH_UNTIMED)
        if figure == "backend_p99_ms":
            return self.throughput.latency_ms["backend"].p99
        return getattr(self.throughput, figure)

    def trajectory_values(self) -> dict[str, Value]:
        """Full-rate ATE/RPE (every frame) and keyframe-only ATE, by the column names tables give them."""
        full, kf = self.full_rate, self.keyframe_trajectory
        return {
            "ate_before_m": full.before.ate_translation_m,
            "ate_after_m": full.after.ate_translation_m,
            "improvement_t_pct": full.improvement.translation,
            "improvement_r_pct": full.improvement.rotation,
            "rpe_pct": full.after.rpe_kitti_translation_pct,
            "rpe_10m_m": full.after.rpe_10m_translation_m,
            "kf_ate_before_m": kf.before.ate_translation_m,
            "kf_ate_after_m": kf.after.ate_translation_m,
            "kf_improvement_t_pct": kf.improvement.translation,
            "kf_improvement_r_pct": kf.improvement.rotation,
        }

    def comparison_row(self, rejection_reasons: Sequence[str]) -> ComparisonRow:
        """compare's Table-I row (reporting.comparison.COLUMNS): full-rate ATE/RPE first, keyframe-only ATE as kf_*
        columns; n/a values as None (their reasons are in the report's notes)."""
        loops, acc, pr = self.loops, self.loops.accounting, self.place_recognition
        reference = pr.reference if isinstance(pr.reference, ReferencePR) else None
        values = self.trajectory_values()
        row: dict[str, Value | None] = {
            "keyframes": self.run.keyframes,
            "candidates": loops.candidates,
            "true_candidates": acc.true_candidates,
            "verified": loops.verified,
            "rejected": loops.rejected,
            **{f"rejected_{reason}": acc.rejected.get(reason, 0) for reason in rejection_reasons},
            "false_loops": loops.false_loops,
            "distant_loops": acc.distant_loops,
            "revisits": acc.revisits,
            "revisit_recall": acc.revisit_recall,
            "revisit_keyframe_recall": acc.revisit_keyframe_recall,
            **{
                k: values[k]
                for k in (
                    "ate_before_m",
                    "ate_after_m",
                    "improvement_t_pct",
                    "improvement_r_pct",
                    "rpe_pct",
                    "rpe_10m_m",
                )
            },
            "pr_auc": pr.pr_auc,
            "f1_max": pr.f1_max,
            "pr_auc_reference": None if reference is None else reference.pr_auc,
            "f1_max_reference": None if reference is None else reference.f1_max,
            "memory_mib": self.memory.total_mib,
            "rss_growth_mib": self.memory.rss_growth_mib,
            "time_s": self.timing.backend_total,
            **{
                k: values[k]
                for k in ("kf_ate_before_m", "kf_ate_after_m", "kf_improvement_t_pct", "kf_improvement_r_pct")
            },
        }
        return ComparisonRow(self.method, {k: known(v) for k, v in row.items()})

    def cell_values(self) -> dict[str, Value]:
        """An experiment cell's metric columns (experiments.report.COLUMNS from `frames` on, but the memory relative
        to the reference cell, which needs another cell's figure)."""
        values = self.trajectory_values()
        del values["kf_improvement_r_pct"]
        return {
            "frames": self.run.frames,
            "keyframes": self.run.keyframes,
            "candidates": self.loops.candidates,
            "verified": self.loops.verified,
            "false_loops": self.loops.false_loops,
            **values,
            "pr_auc": self.place_recognition.pr_auc,
            "f1_max": self.place_recognition.f1_max,
            "memory_mib": self.memory.total_mib,
            "bytes_per_keyframe": self.memory.accounted.total / max(1, self.run.keyframes),
            "time_s": self.timing.backend_total,
            **{figure: self.per_frame(figure) for figure in ("fps", "backend_fps", "backend_p99_ms")},
            "process_peak_rss_mib": self.memory.peak_rss_bytes / 2**20,  # the cell's whole process, not the method
            "rss_growth_mib": self.memory.rss_growth_mib,
            "rejected": self.loops.rejected,
        }
