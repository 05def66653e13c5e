"""The comparison's tables, figures and report.md (experiments.compare runs it; `msa-slam report` writes the
report again from the folder, experiments.rereport): one Table-I row per method, the metrics and trajectory
figures, both protocols' precision-recall curves, the threshold sweep and the memory and time definitions."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

from msa_slam.evaluation import ATE_ALIGNMENT, NA, fmt, notes, peak_rss_bytes
from msa_slam.evaluation.display import spec_for
from msa_slam.evaluation.full_rate import RPE_10M_EVO
from msa_slam.evaluation.loops import FALSE_LOOP_ANGLE_DEG
from msa_slam.evaluation.metrics import Unavailable, known
from msa_slam.evaluation.resources import StageTimer
from msa_slam.evaluation.run_metrics import ComparisonRow, RunMetrics
from msa_slam.io.tables import mib, rows_csv
from msa_slam.pipeline.driver import SWEEP_NOT_RUN
from msa_slam.place_recognition import PRCurve
from msa_slam.place_recognition.figures import plot_pr_curves
from msa_slam.reporting.report import (
    GT_FILE,
    RPE_STATISTICS,
    ReportedRun,
    deskew_text,
    replayed_note,
)
from msa_slam.reporting.results import reference_xy, trajectory_panels
from msa_slam.reporting.sequence_text import rpe_segments, scans_read, sequence_title
from msa_slam.slam import RunResult
from msa_slam.slam.loop_closing import REJECTION_REASONS, candidate_rule
from msa_slam.viz import MethodMetric, plot_method_metrics, plot_trajectories
from msa_slam.viz.labels import absent_note, display_name

_RPE_10M_COMMAND = RPE_10M_EVO.format(
    reference=f"runs/<method>/{GT_FILE}", estimate="runs/<method>/trajectories/optimised.tum"
)


class SharedFrontEnd(Protocol):
    """The comparison's shared front end as its report describes it (pipeline.frontend.CachedFrontEnd, or
    reporting.stored.StoredFrontend read back from the folder)."""

    @property
    def name(self) -> str: ...
    @property
    def timer(self) -> StageTimer: ...
    @property
    def cached(self) -> dict[str, bool]: ...

    def __len__(self) -> int: ...


# Primary columns: full-rate (every frame, the same "ATE before" for every method); kf_*: keyframes only. Loop columns:
# what became of the candidates (rejected_<reason>: slam.loop_closing.REJECTION_REASONS) and, against ground truth,
# how many accepted loops were false (measured pose off) or distant (keyframes far apart) and which share of the
# revisits got one (evaluation.loops).
REJECTED_COLUMNS = tuple(f"rejected_{reason}" for reason in REJECTION_REASONS)
COLUMNS = (
    "method",
    "keyframes",
    "candidates",
    "true_candidates",
    "verified",
    "rejected",
    *REJECTED_COLUMNS,
    "false_loops",
    "distant_loops",
    "revisits",
    "revisit_recall",
    "revisit_keyframe_recall",
    "ate_before_m",
    "ate_after_m",
    "improvement_t_pct",
    "improvement_r_pct",
    "rpe_pct",
    "rpe_10m_m",
    "pr_auc",
    "f1_max",
    "pr_auc_reference",
    "f1_max_reference",
    "memory_mib",
    "rss_growth_mib",
    "time_s",
    "kf_ate_before_m",
    "kf_ate_after_m",
    "kf_improvement_t_pct",
    "kf_improvement_r_pct",
)
HEADERS = (
    "method",
    "keyframes",
    "candidates",
    "true cand.",
    "verified",
    "rejected",
    *(f"rej. {reason}" for reason in REJECTION_REASONS),
    "false loops",
    "distant loops",
    "revisits",
    "revisit recall",
    "revisit kf recall",
    "ATE before [m]",
    "ATE after [m]",
    "t. ATE impr. [%]",
    "R. ATE impr. [%]",
    "RPE {rpe} [%]",
    "RPE 10 m all-pairs mean [m]",
    "PR-AUC",
    "F1-max",
    "PR-AUC (ref.)",
    "F1-max (ref.)",
    "memory [MiB]",
    "RSS growth [MiB]",
    "time [s]",
    "kf ATE before [m]",
    "kf ATE after [m]",
    "kf t. impr. [%]",
    "kf R. impr. [%]",
)


def table_row(metrics: RunMetrics) -> ComparisonRow:
    """One Table-I row (COLUMNS) of a run's report: full-rate ATE/RPE first, keyframe-only ATE as kf_* columns
    (memory: keyframes + graph; RSS growth: the process's settled RSS over the method's back-end, see
    comparison_report; time: back-end stages)."""
    return metrics.comparison_row(REJECTION_REASONS)


def _cell(column: str, value: Any) -> str:
    """A float with its column's decimals (evaluation.display.spec_for), counts and names as they are."""
    if isinstance(value, float):
        return fmt(value, spec_for(column))
    return NA if value is None else str(value)


def table_markdown(rows: Sequence[ComparisonRow], rpe_span: str = "KITTI segments") -> str:
    """comparison.md: the rows of comparison.csv, each column with one number of decimals; `rpe_span`: the
    KITTI segment lengths the RPE covered (reporting.report.rpe_segments), for its header."""
    headers = [h.format(rpe=rpe_span) for h in HEADERS]
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(_cell(c, record[c]) for c in COLUMNS) + " |" for record in (r.record() for r in rows)]
    return "\n".join(lines) + "\n"


def _unavailable(results: Sequence[ReportedRun], *keys: str) -> str:
    """The first reason any method's report gives under `keys` (metrics.json `unavailable`), else ""."""
    return next((r.measured.reasons[k] for r in results for k in keys if r.measured.reasons.get(k)), "")


def method_metrics(results: Sequence[RunResult]) -> list[MethodMetric]:
    """The metrics figure's panels: each method's difference to all samples (the paper's Fig. 5), then the
    absolute ATE with the odometry's (the same for every method) as one line, keyframes and memory."""
    full = [r.measured.full_rate for r in results]
    why = _unavailable(results, "ate", "full_rate_ate_optimised", "full_rate_ate")  # "no ground truth" first
    ate = [known(f.after.ate_translation_m) for f in full]
    memory = [r.measured.memory.total_mib for r in results]
    return [
        MethodMetric("t. ATE", "m", ate, 3, difference=True, why=why),
        MethodMetric("R. ATE", "deg", [known(f.after.ate_rotation_deg) for f in full], 3, difference=True, why=why),
        MethodMetric("memory", "MiB", memory, 2, difference=True),
        MethodMetric("back-end time", "s", [r.measured.timing.backend_total for r in results], 2, difference=True),
        MethodMetric(
            "t. ATE, every frame", "m", ate, 3, why=why, line=("odometry", known(full[0].before.ate_translation_m))
        ),
        MethodMetric("keyframes", "", [r.measured.run.keyframes for r in results], 0),
        MethodMetric("memory (keyframes + graph)", "MiB", memory, 2),
    ]


PR_FIGURES = (
    ("paper", "pr_curves.png", "loop candidates per method (paper: keyframe search)", "pr"),
    ("reference", "pr_curves_reference.png", "best match per frame (reference example's protocol)", "pr_reference"),
)


def write_figures(
    results: Sequence[RunResult], folder: Path, failed: Mapping[str, str], draw: bool = True
) -> list[str]:
    """metrics.png, trajectories.png and the PR curves of both protocols; each names the methods it leaves out
    (`failed`: the methods that failed, with their error). pr.csv, their data, is written whether or not they are
    drawn (`draw`)."""
    folder.mkdir()
    (folder / "pr.csv").write_text(pr_csv(results))
    if not draw:
        return []
    labels = [r.config.name for r in results]
    sequence = sequence_title(results[0].measured.run.sequence, results[0].config.source, len(results[0]))
    gone = {name: "failed" for name in failed}
    plot_method_metrics(
        folder / "metrics.png",
        labels,
        method_metrics(results),
        reference="all",
        title=f"{sequence} ({results[0].config.mode} loops); top: difference to all samples, "
        f"below 0 (green) is lower" + absent_note(gone, "; "),
    )
    panels = [trajectory_panels(r)[1] for r in results]
    plot_trajectories(
        folder / "trajectories.png",
        reference_xy(results[0]),
        [trajectory_panels(results[0])[0], *panels],
        title=f"{sequence}: keyframe trajectories of every sampler after optimisation"
        + (", coloured by ATE" if results[0].gt_poses is not None else "")
        + absent_note(gone, "\n"),
    )
    names = ["metrics.png", "trajectories.png"]
    for protocol, file, what, key in PR_FIGURES:
        curves = {r.config.name: c for r in results if (c := _pr(r, protocol)) is not None and c.auc is not None}
        absent = {
            **{
                r.config.name: r.measured.reasons.get(key) or "no loop candidates"
                for r in results
                if r.config.name not in curves
            },
            **gone,
        }
        if curves:
            plot_pr_curves(curves, folder / file, title=f"{sequence}: {what}", absent=absent)
            names.append(file)
    return names


def _pr(result: RunResult, protocol: str) -> PRCurve | None:
    return result.pr if protocol == "paper" else result.pr_reference


PR_COLUMNS = ("method", "protocol", "threshold", "precision", "recall", "f1")


def pr_csv(results: Sequence[RunResult]) -> str:
    """Both protocols' precision/recall arrays of every method (one row per threshold; no rows for a method
    without recorded matches)."""
    rows = [
        {
            "method": r.config.name,
            "protocol": protocol,
            "threshold": f"{t:.2f}",
            "precision": f"{p:.6f}",
            "recall": f"{q:.6f}",
            "f1": f"{f:.6f}",
        }
        for r in results
        for protocol in ("paper", "reference")
        if (c := _pr(r, protocol)) is not None
        for t, p, q, f in zip(c.thresholds, c.precision, c.recall, c.f1)
    ]
    return rows_csv(rows, PR_COLUMNS)


def sweep_markdown(results: Sequence[ReportedRun]) -> str:
    """Loops accepted and full-rate t. ATE improvement per method at each threshold of the sweep."""
    swept = [(r, rows) for r in results if not isinstance(rows := r.measured.place_recognition.sweep, Unavailable)]
    if not swept:
        return ""
    thresholds = [row.threshold for row in swept[0][1]]
    lines = ["| method | " + " | ".join(f"{t:.2f}" for t in thresholds) + " |", "|" + "---|" * (len(thresholds) + 1)]
    for r, rows in swept:
        cells = {row.threshold: f"{row.loops_accepted} / {fmt(row.improvement_t_pct, '.1f', ' %')}" for row in rows}
        lines.append(f"| {r.config.name} | " + " | ".join(cells.get(t, NA) for t in thresholds) + " |")
    return "\n".join(lines) + "\n"


# Where a comparison's methods ran: `workers` and the main process's peak RSS as report.md gives it (with several
# workers); how the run was executed, not a result, so kept apart from comparison.json for `msa-slam report`
PROCESSES = "processes.json"


def comparison_report(
    fe: SharedFrontEnd,
    results: Sequence[ReportedRun],
    table: str,
    figures: list[str],
    workers: int,
    main_peak: str | None = None,
) -> str:
    """report.md; `workers`: the processes the methods ran in (1: this one), which the memory figures depend on;
    `main_peak`: the main process's peak RSS as report.md gives it (default: this process's peak now)."""
    cfg = results[0].config
    rpe_text = rpe_segments(results[0].gt_poses)[1]  # every method runs on the same sequence
    front = ", ".join(f"{k} {v:.1f} s" for k, v in fe.timer.seconds.items())
    lines = [
        f"# Sampler comparison on {display_name(fe.name)}",
        "",
        f"Dataset `{cfg.dataset}` (sequence {fe.name}), {scans_read(cfg.source)}: {len(fe)} frames. "
        f"Odometry `{cfg.odometry}`, descriptor `{cfg.descriptor}`, "
        f"loops: {candidate_rule(cfg)}, {cfg.mode} verification (small_gicp residual < "
        f"{cfg.verifier.max_residual} m), GTSAM Levenberg-Marquardt. Shared front end: {front}"
        f"{replayed_note(fe.cached)}. {deskew_text(results[0].measured.setup.deskew)}".rstrip(),
        "",
        *(
            []
            if results[0].gt_poses is not None
            else [
                "No ground truth: ATE, RPE, PR-AUC / F1-max and false loops are n/a for every method (the "
                "definitions below apply to a sequence with ground truth).",
                "",
            ]
        ),
        f"ATE: the full-rate trajectory (every frame: its preceding keyframe's optimised pose and the "
        f"odometry since) vs ground truth after {ATE_ALIGNMENT} alignment (fitted on all frames of each "
        "estimate), before (odometry, the same for every method) and after pose-graph optimisation; "
        f"improvement = 100 (before - after) / before. {rpe_text}. RPE is of the full-rate optimised "
        f"trajectory (translation in % of the segment length), also over 10 m (m). {RPE_STATISTICS} "
        + (f"`{_RPE_10M_COMMAND}` prints a method's 10 m RPE as its mean. " if results[0].gt_poses is not None else "")
        + "kf columns: the same ATE on "
        "each method's own keyframes only. PR-AUC / F1-max: the paper's keyframe search (each keyframe's best "
        "older match) and, marked ref., the reference example's protocol (each frame against the 10 nearest "
        "keyframes); arrays in figures/pr.csv. False loops: accepted loops whose measured relative pose is off "
        f"ground truth by more than {cfg.loop_radius} m or {FALSE_LOOP_ANGLE_DEG:g} deg (a wrong constraint in the "
        f"graph); distant loops: accepted loops whose keyframes are more than {cfg.loop_radius} m apart in ground "
        "truth (not wrong when their pose is right). Memory: accounted bytes of keyframe descriptors, "
        "downsampled keyframe clouds and the graph, per method; RSS growth: the process's resident set at the end of the method's back-end "
        "(after the final optimisation) minus at its start, both read after a full garbage collection and "
        "with free heap pages handed back (malloc_trim), so memory an earlier method freed counts neither for "
        f"nor against this one ({_processes(workers)}). It is what the back-end added "
        "and still holds at its end: the memory column plus what that leaves out (per-frame records, the map, "
        "the sampler's working buffers such as MSA's exact-search workspace, allocator overheads). MSA's numba "
        "kernels are loaded before its back-end starts (a one-time cost of the process, ~58 MiB). Time: "
        "sampling + keyframe store + loop search + verification + optimisation.",
        "",
        table,
        "",
        *_sweep_lines(results),
        _peak_rss(results, workers, main_peak),
        "",
    ]
    method_notes = [
        f"- {r.config.name}: {note}" for r in results for note in notes(r.measured.reasons, r.measured.warnings)
    ]
    if method_notes:
        lines += ["Notes (n/a values and warnings):", "", *method_notes, ""]
    lines += [f"![{n}](figures/{n})" for n in figures]
    lines += [
        "",
        "Per-method results: " + ", ".join(f"[{r.config.name}](runs/{r.config.name}/report.md)" for r in results),
        "",
    ]
    return "\n".join(lines)


def _processes(workers: int) -> str:
    """Where the methods ran, for the RSS growth's definition in report.md."""
    if workers == 1:
        return "methods run one after another in one process"
    return (
        f"methods run one after another in each of {workers} worker processes forked from the main one after "
        "the front end, so a worker's first method, not only the comparison's first, carries the one-time "
        "costs of a back-end in a process"
    )


def _peak_rss(results: Sequence[ReportedRun], workers: int, main_peak: str | None = None) -> str:
    """The peak-RSS line of report.md: of the one process, or of the busiest worker and of the main process
    (`main_peak`, else this process's peak now)."""
    peak = mib(max(r.measured.memory.peak_rss_bytes for r in results))
    if workers == 1:
        return (
            f"Process peak RSS: {peak} (whole process: every method and the shared front end; not a per-method figure)."
        )
    return (
        f"Peak RSS: {peak} in the busiest worker process (its methods and the front end, which it shares with "
        f"the main process and so is counted in each: the figures do not add up), {main_peak or mib(peak_rss_bytes())} in "
        "the main process (the front end, tables and figures); not per-method figures."
    )


def _sweep_lines(results: Sequence[ReportedRun]) -> list[str]:
    sweep = sweep_markdown(results)
    if not sweep:
        reasons = {r.measured.reasons.get("threshold_sweep") for r in results}
        if reasons == {SWEEP_NOT_RUN}:
            return [f"Threshold sensitivity: {SWEEP_NOT_RUN}.", ""]
        return []  # why is in each method's notes
    return [
        "Threshold sensitivity: loops accepted / full-rate t. ATE improvement when only the back-end (loop "
        "closing + optimisation) is re-run on the same keyframes with another similarity threshold:",
        "",
        sweep,
        "",
    ]


def failed_section(failed: dict[str, str]) -> str:
    """The report's list of the methods that failed (empty when none did)."""
    if not failed:
        return ""
    return "\n## Failed methods\n\n" + "".join(
        f"- {name}: {error} (traceback: runs/{name}/error.txt)\n" for name, error in failed.items()
    )
