"""The paper's method set on one sequence (Table I): all samples, constant 1/2/3 m, entropy, spaciousness, MSA.

Odometry and descriptors are computed once and shared; each method gets its own run folder under runs/,
and the comparison (Markdown + CSV + figures + report.md) sits at the top of the output folder.
"""

from __future__ import annotations

import logging
import os
import sys
import traceback
from concurrent.futures import as_completed
from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping, Sequence

from msa_slam.errors import InputError
from msa_slam.evaluation import ATE_ALIGNMENT, NA, fmt, notes, peak_rss_bytes
from msa_slam.evaluation.display import spec_for
from msa_slam.evaluation.full_rate import RPE_10M_EVO
from msa_slam.evaluation.metrics import Unavailable, known
from msa_slam.evaluation.metrics_json import to_json
from msa_slam.evaluation.run_metrics import RunMetrics, TableRow
from msa_slam.io.atomic import atomic_path, write_text_atomic
from msa_slam.io.outputs import DEFAULT_RESULTS, open_result_folder, staged_dir
from msa_slam.io.tables import mib, rows_csv, write_json
from msa_slam.pipeline.batch import SWEEP_NOT_RUN, run_batch
from msa_slam.pipeline.config import RunConfig, make_config
from msa_slam.pipeline.frontend import CONFIG_WINDOW_FIX, Frontend, prepare_frontend
from msa_slam.pipeline.report import (GT_FILE, RPE_STATISTICS, deskew_text, replayed_note, rpe_segments, scans_read,
                                     sequence_title)
from msa_slam.pipeline.results import reference_xy, trajectory_panels, write_run_files
from msa_slam.pipeline.seed_folder import (RECORD, check_seed_folder, clean_leftovers, finished_metrics, left_out_seeds,
                                           remove_seeds, resume_seeds, seed_dir, seed_identities, seed_record,
                                           write_record)
from msa_slam.pipeline.seeds import SEED_COLUMNS, seed_markdown, seed_rows, seed_summary, seeded_datasets
from msa_slam.place_recognition import PRCurve
from msa_slam.place_recognition.figures import plot_pr_curves
from msa_slam.progress import progress_bar
from msa_slam.sampling.params import GATE_PARAMETERS
from msa_slam.slam import RunResult
from msa_slam.slam.backend import UNGATED_SAMPLERS
from msa_slam.slam.loop_closing import REJECTION_REASONS, candidate_rule
from msa_slam.viz import MethodMetric, plot_method_metrics, plot_trajectories
from msa_slam.viz.labels import absent_note, display_name
from msa_slam.workers import check_workers, forked_workers, shared

log = logging.getLogger(__name__)

# (label, sampler, parameters) as in the paper's section V.
PAPER_METHODS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("all", "all", {}),
    ("constant-1m", "constant", {"distance": 1.0}),
    ("constant-2m", "constant", {"distance": 2.0}),
    ("constant-3m", "constant", {"distance": 3.0}),
    ("entropy", "entropy", {}),
    ("spaciousness", "spaciousness", {}),
    ("msa", "msa", {}),
)
_RPE_10M_COMMAND = RPE_10M_EVO.format(reference=f"runs/<method>/{GT_FILE}",
                                      estimate="runs/<method>/trajectories/optimised.tum")
UNDER_STUDY = "msa"  # the sampler that gets the user's sampler parameters (method_configs)

# Primary columns: full-rate (every frame, the same "ATE before" for every method); kf_*: keyframes only. Loop columns:
# what became of the candidates (rejected_<reason>: slam.loop_closing.REJECTION_REASONS) and, against ground truth,
# how many accepted loops were false and which share of the revisits got one (evaluation.loops).
REJECTED_COLUMNS = tuple(f"rejected_{reason}" for reason in REJECTION_REASONS)
COLUMNS = ("method", "keyframes", "candidates", "true_candidates", "verified", "rejected", *REJECTED_COLUMNS,
           "false_loops", "false_accepted", "revisits", "revisit_recall", "revisit_keyframe_recall", "ate_before_m",
           "ate_after_m", "improvement_t_pct", "improvement_r_pct", "rpe_pct", "rpe_10m_m", "pr_auc", "f1_max",
           "pr_auc_reference", "f1_max_reference", "memory_mib", "rss_growth_mib", "time_s", "kf_ate_before_m",
           "kf_ate_after_m", "kf_improvement_t_pct", "kf_improvement_r_pct")
HEADERS = ("method", "keyframes", "candidates", "true cand.", "verified", "rejected",
           *(f"rej. {reason}" for reason in REJECTION_REASONS), "false loops", "false accepted", "revisits",
           "revisit recall", "revisit kf recall", "ATE before [m]", "ATE after [m]", "t. ATE impr. [%]",
           "R. ATE impr. [%]", "RPE {rpe} [%]", "RPE 10 m all-pairs mean [m]", "PR-AUC", "F1-max", "PR-AUC (ref.)",
           "F1-max (ref.)", "memory [MiB]", "RSS growth [MiB]", "time [s]", "kf ATE before [m]", "kf ATE after [m]",
           "kf t. impr. [%]", "kf R. impr. [%]")


def table_row(metrics: RunMetrics) -> TableRow:
    """One Table-I row (COLUMNS) of a run's report: full-rate ATE/RPE first, keyframe-only ATE as kf_* columns
    (memory: keyframes + graph; RSS growth: the process's settled RSS over the method's back-end, see
    comparison_report; time: back-end stages)."""
    return metrics.comparison_row(REJECTION_REASONS)


def _cell(column: str, value: Any) -> str:
    """A float with its column's decimals (evaluation.display.spec_for), counts and names as they are."""
    if isinstance(value, float):
        return fmt(value, spec_for(column))
    return NA if value is None else str(value)


def table_markdown(rows: Sequence[TableRow], rpe_span: str = "KITTI segments") -> str:
    """comparison.md: the rows of comparison.csv, each column with one number of decimals; `rpe_span`: the
    KITTI segment lengths the RPE covered (pipeline.report.rpe_segments), for its header."""
    headers = [h.format(rpe=rpe_span) for h in HEADERS]
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(_cell(c, r[c]) for c in COLUMNS) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _unavailable(results: Sequence[RunResult], *keys: str) -> str:
    """The first reason any method's report gives under `keys` (metrics.json `unavailable`), else ""."""
    return next((r.metrics.reasons[k] for r in results for k in keys if r.metrics.reasons.get(k)), "")


def method_metrics(results: Sequence[RunResult]) -> list[MethodMetric]:
    """The metrics figure's panels: each method's difference to all samples (the paper's Fig. 5), then the
    absolute ATE with the odometry's (the same for every method) as one line, keyframes and memory."""
    full = [r.metrics.full_rate for r in results]
    why = _unavailable(results, "ate", "full_rate_ate_optimised", "full_rate_ate")  # "no ground truth" first
    ate = [known(f.after.ate_translation_m) for f in full]
    memory = [r.metrics.memory.total_mib for r in results]
    return [
        MethodMetric("t. ATE", "m", ate, 3, difference=True, why=why),
        MethodMetric("R. ATE", "deg", [known(f.after.ate_rotation_deg) for f in full], 3, difference=True, why=why),
        MethodMetric("memory", "MiB", memory, 2, difference=True),
        MethodMetric("back-end time", "s", [r.metrics.timing.backend_total for r in results], 2,
                     difference=True),
        MethodMetric("t. ATE, every frame", "m", ate, 3, why=why,
                     line=("odometry", known(full[0].before.ate_translation_m))),
        MethodMetric("keyframes", "", [r.metrics.run.keyframes for r in results], 0),
        MethodMetric("memory (keyframes + graph)", "MiB", memory, 2),
    ]


PR_FIGURES = (("paper", "pr_curves.png", "loop candidates per method (paper: keyframe search)", "pr"),
              ("reference", "pr_curves_reference.png", "best match per frame (reference example's protocol)",
               "pr_reference"))


def _figures(results: Sequence[RunResult], folder: Path, failed: Mapping[str, str], draw: bool = True) -> list[str]:
    """metrics.png, trajectories.png and the PR curves of both protocols; each names the methods it leaves out
    (`failed`: the methods that failed, with their error). pr.csv, their data, is written whether or not they are
    drawn (`draw`)."""
    folder.mkdir()
    (folder / "pr.csv").write_text(pr_csv(results))
    if not draw:
        return []
    labels = [r.config.name for r in results]
    sequence = sequence_title(results[0].metrics.run.sequence, results[0].config.source, len(results[0]))
    gone = {name: "failed" for name in failed}
    plot_method_metrics(folder / "metrics.png", labels, method_metrics(results), reference="all",
                        title=f"{sequence} ({results[0].config.mode} loops); top: difference to all samples, "
                              f"below 0 (green) is lower" + absent_note(gone, "; "))
    panels = [trajectory_panels(r)[1] for r in results]
    plot_trajectories(folder / "trajectories.png", reference_xy(results[0]),
                      [trajectory_panels(results[0])[0], *panels],
                      title=f"{sequence}: keyframe trajectories of every sampler after optimisation"
                            + (", coloured by ATE" if results[0].gt_poses is not None else "")
                            + absent_note(gone, "\n"))
    names = ["metrics.png", "trajectories.png"]
    for protocol, file, what, key in PR_FIGURES:
        curves = {r.config.name: c for r in results if (c := _pr(r, protocol)) is not None and c.auc is not None}
        absent = {**{r.config.name: r.metrics.reasons.get(key) or "no loop candidates"
                     for r in results if r.config.name not in curves}, **gone}
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
    rows = [{"method": r.config.name, "protocol": protocol, "threshold": f"{t:.2f}", "precision": f"{p:.6f}",
             "recall": f"{q:.6f}", "f1": f"{f:.6f}"}
            for r in results for protocol in ("paper", "reference") if (c := _pr(r, protocol)) is not None
            for t, p, q, f in zip(c.thresholds, c.precision, c.recall, c.f1)]
    return rows_csv(rows, PR_COLUMNS)


def sweep_markdown(results: Sequence[RunResult]) -> str:
    """Loops accepted and full-rate t. ATE improvement per method at each threshold of the sweep."""
    swept = [r for r in results if not isinstance(r.metrics.place_recognition.sweep, Unavailable)]
    if not swept:
        return ""
    thresholds = [row.threshold for row in swept[0].metrics.place_recognition.sweep]
    lines = ["| method | " + " | ".join(f"{t:.2f}" for t in thresholds) + " |", "|" + "---|" * (len(thresholds) + 1)]
    for r in swept:
        cells = {row.threshold: f"{row.loops_accepted} / {fmt(row.improvement_t_pct, '.1f', ' %')}"
                 for row in r.metrics.place_recognition.sweep}
        lines.append(f"| {r.config.name} | " + " | ".join(cells.get(t, NA) for t in thresholds) + " |")
    return "\n".join(lines) + "\n"


# Where a comparison's methods ran: `workers` and the main process's peak RSS as report.md gives it (with several
# workers); how the run was executed, not a result, so kept apart from comparison.json for `msa-slam report`
PROCESSES = "processes.json"


def comparison_report(fe: Frontend, results: Sequence[RunResult], table: str, figures: list[str], workers: int,
                      main_peak: str | None = None) -> str:
    """report.md; `workers`: the processes the methods ran in (1: this one), which the memory figures depend on;
    `main_peak`: the main process's peak RSS as report.md gives it (default: this process's peak now)."""
    cfg = results[0].config
    rpe_text = rpe_segments(results[0].gt_poses)[1]  # every method runs on the same sequence
    front = ", ".join(f"{k} {v:.1f} s" for k, v in fe.timer.seconds.items())
    lines = [f"# Sampler comparison on {display_name(fe.name)}", "",
             f"Dataset `{cfg.dataset}` (sequence {fe.name}), {scans_read(cfg.source)}: {len(fe)} frames. "
             f"Odometry `{cfg.odometry}`, descriptor `{cfg.descriptor}`, "
             f"loops: {candidate_rule(cfg)}, {cfg.mode} verification (small_gicp residual < "
             f"{cfg.verifier.max_residual} m), GTSAM Levenberg-Marquardt. Shared front end: {front}"
             f"{replayed_note(fe.cached)}. {deskew_text(results[0].metrics.setup.deskew)}".rstrip(), "",
             *([] if results[0].gt_poses is not None else [
                 "No ground truth: ATE, RPE, PR-AUC / F1-max and false loops are n/a for every method (the "
                 "definitions below apply to a sequence with ground truth).", ""]),
             f"ATE: the full-rate trajectory (every frame: its preceding keyframe's optimised pose and the "
             f"odometry since) vs ground truth after {ATE_ALIGNMENT} alignment (fitted on all frames of each "
             "estimate), before (odometry, the same for every method) and after pose-graph optimisation; "
             f"improvement = 100 (before - after) / before. {rpe_text}. RPE is of the full-rate optimised "
             f"trajectory (translation in % of the segment length), also over 10 m (m). {RPE_STATISTICS} "
             + (f"`{_RPE_10M_COMMAND}` prints a method's 10 m RPE as its mean. " if results[0].gt_poses is not None
                else "") + "kf columns: the same ATE on "
             "each method's own keyframes only. PR-AUC / F1-max: the paper's keyframe search (each keyframe's best "
             "older match) and, marked ref., the reference example's protocol (each frame against the 10 nearest "
             "keyframes); arrays in figures/pr.csv. False loops: verified loops whose ground-truth distance exceeds "
             f"{cfg.loop_radius} m. Memory: accounted bytes of keyframe descriptors, downsampled keyframe clouds "
             "and the graph, per method; RSS growth: the process's resident set at the end of the method's back-end "
             "(after the final optimisation) minus at its start, both read after a full garbage collection and "
             "with free heap pages handed back (malloc_trim), so memory an earlier method freed counts neither for "
             f"nor against this one ({_processes(workers)}). It is what the back-end added "
             "and still holds at its end: the memory column plus what that leaves out (per-frame records, the map, "
             "the sampler's working buffers such as MSA's exact-search workspace, allocator overheads). MSA's numba "
             "kernels are loaded before its back-end starts (a one-time cost of the process, ~58 MiB). Time: "
             "sampling + keyframe store + loop search + verification + optimisation.", "", table, "",
             *_sweep_lines(results),
             _peak_rss(results, workers, main_peak), ""]
    method_notes = [f"- {r.config.name}: {note}" for r in results
                    for note in notes(r.metrics.reasons, r.metrics.warnings)]
    if method_notes:
        lines += ["Notes (n/a values and warnings):", "", *method_notes, ""]
    lines += [f"![{n}](figures/{n})" for n in figures]
    lines += ["", "Per-method results: " + ", ".join(f"[{r.config.name}](runs/{r.config.name}/report.md)"
                                                  for r in results), ""]
    return "\n".join(lines)


def _processes(workers: int) -> str:
    """Where the methods ran, for the RSS growth's definition in report.md."""
    if workers == 1:
        return "methods run one after another in one process"
    return (f"methods run one after another in each of {workers} worker processes forked from the main one after "
            "the front end, so a worker's first method, not only the comparison's first, carries the one-time "
            "costs of a back-end in a process")


def _peak_rss(results: Sequence[RunResult], workers: int, main_peak: str | None = None) -> str:
    """The peak-RSS line of report.md: of the one process, or of the busiest worker and of the main process
    (`main_peak`, else this process's peak now)."""
    peak = mib(max(r.metrics.memory.peak_rss_bytes for r in results))
    if workers == 1:
        return (f"Process peak RSS: {peak} (whole process: every method and the shared front end; not a per-method "
                "figure).")
    return (f"Peak RSS: {peak} in the busiest worker process (its methods and the front end, which it shares with "
            f"the main process and so is counted in each: the figures do not add up), {main_peak or mib(peak_rss_bytes())} in "
            "the main process (the front end, tables and figures); not per-method figures.")


def _sweep_lines(results: Sequence[RunResult]) -> list[str]:
    sweep = sweep_markdown(results)
    if not sweep:
        reasons = {r.metrics.reasons.get("threshold_sweep") for r in results}
        if reasons == {SWEEP_NOT_RUN}:
            return [f"Threshold sensitivity: {SWEEP_NOT_RUN}.", ""]
        return []  # why is in each method's notes
    return ["Threshold sensitivity: loops accepted / full-rate t. ATE improvement when only the back-end (loop "
            "closing + optimisation) is re-run on the same keyframes with another similarity threshold:", "",
            sweep, ""]


def method_configs(base: RunConfig, methods: Sequence[tuple[str, str, dict[str, Any]]] = PAPER_METHODS
                   ) -> list[RunConfig]:
    """One validated config per method: `base` with the method's sampler, parameters and label.

    When `base` is a config of the sampler under study (UNDER_STUDY), its sampler parameters (-p window=8,
    -p sampler.lambda_u=5) go to every method of that sampler, under the method's own, so compare measures
    the MSA the user asked for; the baselines keep the paper's settings (check_compare_sampler refuses
    parameters given for another sampler, which would have nowhere to go). The standstill gate's parameters
    (min_motion, min_rotation) are the exception: they go to every method but those the SLAM core leaves ungated
    ("all"), so that all methods are compared on the same frames."""
    data = base.dump()
    given = base.sampler_params if base.sampler == UNDER_STUDY else {}
    gate = {k: v for k, v in given.items() if k in GATE_PARAMETERS}

    def params_of(sampler: str, params: dict[str, Any]) -> dict[str, Any]:
        if sampler == UNDER_STUDY:
            return {**given, **params}
        return params if sampler in UNGATED_SAMPLERS else {**gate, **params}

    return [make_config({**data, "sampler": sampler, "sampler_params": params_of(sampler, params), "label": label})
            for label, sampler, params in methods]


def check_compare_sampler(base: RunConfig) -> None:
    """compare runs the paper's methods and gives the sampler parameters to MSA: parameters given for another
    sampler (-p sampler=constant -p distance=2) would be dropped without a word, so they are refused."""
    if base.sampler != UNDER_STUDY and base.sampler_params:
        given = ", ".join(f"{k}={v!r}" for k, v in base.sampler_params.items())
        raise InputError(f"compare: the sampler parameters go to {UNDER_STUDY} (the baselines keep the paper's "
                         f"settings); {given} are for sampler {base.sampler!r}: drop them, or give them to "
                         f"`msa-slam run -p sampler={base.sampler}`")


class MethodsFailed(Exception):
    """Some methods of a comparison failed; the others' results were written (`report`), the failures listed."""

    def __init__(self, report: Path, failed: dict[str, str]) -> None:
        super().__init__(f"{len(failed)} method(s) failed: " + "; ".join(f"{k}: {v}" for k, v in failed.items()))
        self.report, self.failed = report, failed


def run_compare(base: RunConfig, out: str | os.PathLike | None, quiet: bool = True,
                methods: Sequence[tuple[str, str, dict[str, Any]]] = PAPER_METHODS, overwrite: bool = False,
                default_parent: Path = DEFAULT_RESULTS / "compare", seeds: Sequence[int] | None = None,
                sweep: bool = True, window_fix: str = CONFIG_WINDOW_FIX, workers: int = 1, figures: bool = True
                ) -> Path:
    """Run every method on the sequence of `base` and write the comparison folder; return its report.md.

    `out` is checked before any work (msa_slam.io.outputs; None: a new timestamped folder under
    `default_parent`) and appears only when complete. A method that fails does not cost the others: the
    folder is written with the methods that finished, the failed ones are marked in report.md (their
    traceback in runs/<method>/error.txt), and MethodsFailed is raised afterwards.

    `seeds` (simulated data only) repeats the comparison on each world seed under seeds/seed-<n>/ and
    writes the spread over seeds (seeds.md, seeds.csv, seeds.json) and its report.md at the top. That folder
    grows in place so an interrupted run resumes: each seed appears when complete, and a rerun reuses the
    finished seeds run with the same settings on the same data and code, and reruns those whose data or code
    changed since (msa_slam.pipeline.seed_folder); `overwrite` starts afresh.

    `sweep=False` leaves out each method's threshold sweep (pipeline/sweep.py), about half of a method's time;
    `figures=False` the PNG figures (the comparison's and each method's, most of a short comparison's time):
    the tables and data files are the same. It is no setting a resumed seed must match.
    A method whose sampler window the frames read never fill is refused before the shared front end
    (prepare_frontend; `window_fix`: what the error says to change).

    `workers` > 1 runs the methods (of each seed) in that many worker processes forked from this one after the
    front end (_run_methods, msa_slam.workers); the files are byte for byte those of a serial run, but for the
    measured times and memory.
    """
    check_workers(workers)
    plans = None if seeds is None else {seed: method_configs(make_config({**base.dump(), "dataset": dataset}), methods)
                                        for seed, dataset in zip(seeds, seeded_datasets(base.dataset, seeds))}
    with open_result_folder(out, "compare", default_parent, overwrite=overwrite, resume=plans is not None) as folder:
        if plans is None:
            with folder.staging() as tmp:
                _, failed = _comparison(method_configs(base, methods), tmp, quiet, sweep, window_fix, workers,
                                        figures)
        else:
            if not overwrite:
                check_seed_folder(folder.path)
            grown = folder.prepare_in_place(fresh=overwrite, grows=("seeds",), unit_record=RECORD)
            failed = _seed_comparisons(base, plans, grown, quiet, sweep, window_fix, workers, figures)
            folder.record_files()
    if failed:
        raise MethodsFailed(folder.path / "report.md", failed)
    return folder.path / "report.md"


def _comparison(configs: Sequence[RunConfig], tmp: Path, quiet: bool, sweep: bool, window_fix: str, workers: int,
                figures: bool = True) -> tuple[list[TableRow], dict[str, str]]:
    """One comparison folder's files in `tmp` (the methods in `workers` processes); its table rows and failed
    methods."""
    workers = min(workers, len(configs))  # no idle workers
    frontend = prepare_frontend(configs[0], quiet, configs, window_fix)
    results, failed = _run_methods(configs, frontend, tmp / "runs", quiet, sweep, workers, figures)
    rows = [table_row(r.metrics) for r in results]
    table = table_markdown(rows, rpe_segments(results[0].gt_poses)[0] if results else "KITTI segments")
    (tmp / "comparison.md").write_text(table)
    (tmp / "comparison.csv").write_text(rows_csv(rows, COLUMNS))
    write_json(tmp / "comparison.json", [to_json(r.metrics) for r in results])
    drawn = _figures(results, tmp / "figures", failed, figures) if results else []
    main_peak = mib(peak_rss_bytes())
    write_json(tmp / PROCESSES, {"workers": workers, "main_peak_rss": main_peak})
    report = (comparison_report(frontend, results, table, drawn, workers, main_peak) if results
              else f"# Sampler comparison on {display_name(frontend.name)}\n")
    (tmp / "report.md").write_text(report + failed_section(failed))
    return rows, failed


def failed_section(failed: dict[str, str]) -> str:
    """The report's list of the methods that failed (empty when none did)."""
    if not failed:
        return ""
    return "\n## Failed methods\n\n" + "".join(f"- {name}: {error} (traceback: runs/{name}/error.txt)\n"
                                                for name, error in failed.items())


def _seed_comparisons(base: RunConfig, plans: dict[int, list[RunConfig]], out: Path, quiet: bool,
                      sweep: bool, window_fix: str, workers: int, figures: bool = True) -> dict[str, str]:
    """Each seed's comparison (`plans`: seed -> method configs) under out/seeds/, reusing the ones finished
    earlier with the same settings, data and code (a seed whose data or code changed is removed and rerun, with
    a warning and a line in report.md), then the spread over seeds at the top of `out`."""
    records = {seed: seed_record(base.dataset, configs, sweep) for seed, configs in plans.items()}
    identities = seed_identities(plans)
    clean_leftovers(out)
    resume = resume_seeds(out, records, identities)  # refuses other settings before any work
    remove_seeds(out, resume.rerun)
    for line in resume.rerun.values():
        log.warning("compare: %s", line)
    rows, failed = {}, {}
    for seed, configs in plans.items():
        target = seed_dir(out, seed)
        if seed in resume.reusable:
            _say(quiet, f"seed {seed}: reused (finished earlier with the same settings, data and code)")
        else:
            _say(quiet, f"seed {seed}: running")
            with staged_dir(target) as tmp:
                _, seed_failed = _comparison(configs, tmp, quiet, sweep, window_fix, workers, figures)
                write_record(tmp, records[seed], identities[seed], seed_failed)
            failed.update({f"seed {seed}: {name}": error for name, error in seed_failed.items()})
        rows[seed] = [table_row(m) for m in finished_metrics(target) or []]
    write_spread(out, base, rows, failed, left_out_seeds(out, list(plans)), list(resume.rerun.values()))
    return failed


def _say(quiet: bool, line: str) -> None:
    if not quiet:
        print(line, file=sys.stderr, flush=True)


def write_spread(out: Path, base: RunConfig, rows: dict[int, list[TableRow]], failed: dict[str, str],
                  left_out: list[int], rerun: Sequence[str] = ()) -> None:
    """seeds.md, seeds.csv, seeds.json and report.md at the top of `out`, each replaced atomically; `rerun`: the
    lines of the seeds this run reran because their data or code changed, listed in report.md."""
    summary = seed_summary(rows)
    table = seed_markdown(summary)
    write_text_atomic(out / "seeds.md", table)
    write_text_atomic(out / "seeds.csv", rows_csv(seed_rows(summary), SEED_COLUMNS))
    with atomic_path(out / "seeds.json") as path:
        write_json(path, summary.to_json())
    lines = [f"# Sampler comparison over world seeds: `{base.dataset}`", "",
             "Each seed simulates a different world along the same trajectory; every seed's full comparison "
             "(table, figures, per-method runs) is under seeds/seed-<n>/. Metrics as in those reports (ATE and "
             f"improvement on the full-rate trajectory). Scans read on every seed: {scans_read(base.source)}.", "",
             table]
    lines += [f"- [seed {s}](seeds/seed-{s}/report.md)" for s in rows]
    if left_out:
        lines += ["", "Also in seeds/, left out of the spread (not among --seeds): "
                  + ", ".join(f"[seed {s}](seeds/seed-{s}/report.md)" for s in left_out)]
    if rerun:
        lines += ["", "Seeds rerun by this run, their earlier results replaced:", "", *(f"- {line}" for line in rerun)]
    if failed:
        lines += ["", "## Failed methods", "", *(f"- {k}: {v}" for k, v in failed.items())]
    write_text_atomic(out / "report.md", "\n".join(lines) + "\n")


Outcome = tuple[RunResult | None, str | None]  # a method's result, or None and the line saying why it failed


def _run_methods(configs: Sequence[RunConfig], frontend: Frontend, runs: Path, quiet: bool, sweep: bool,
                 workers: int = 1, figures: bool = True) -> tuple[list[RunResult], dict[str, str]]:
    """Each method's run folder under `runs` (a failing method leaves its error.txt instead); the results and the
    failures, both in method order. With `workers` > 1 the methods run in that many processes forked from this
    one (msa_slam.workers: they share the front end), each running its methods one after another."""
    runs.mkdir()
    for cfg in configs:
        (runs / cfg.name).mkdir()
    outcomes = (_serial(configs, frontend, runs, quiet, sweep, figures) if workers == 1
                else _parallel(configs, frontend, runs, quiet, sweep, workers, figures))
    results = [result for result, _ in outcomes if result is not None]
    failed = {cfg.name: error for cfg, (_, error) in zip(configs, outcomes) if error is not None}
    return results, failed


def _serial(configs: Sequence[RunConfig], frontend: Frontend, runs: Path, quiet: bool, sweep: bool,
            figures: bool = True) -> list[Outcome]:
    """The methods one after another in this process, each showing its back-end's progress."""
    outcomes = []
    with progress_bar(quiet, transient=False) as bar:
        task = bar.add_task("methods", total=len(configs))
        for cfg in configs:
            bar.update(task, description=f"method {cfg.name}")
            outcomes.append(_run_method(cfg, frontend, runs / cfg.name, quiet, sweep, figures))
            bar.advance(task)
    return outcomes


def _parallel(configs: Sequence[RunConfig], frontend: Frontend, runs: Path, quiet: bool, sweep: bool,
              workers: int, figures: bool = True) -> list[Outcome]:
    """The methods in `workers` forked processes; one bar, advancing as methods finish (in whatever order)."""
    outcomes: list[Outcome] = [(None, None)] * len(configs)
    with forked_workers(workers, frontend) as submit:
        futures = {submit(_method_in_worker, cfg, runs / cfg.name, sweep, figures): i
                   for i, cfg in enumerate(configs)}
        with progress_bar(quiet, transient=False) as bar:  # after the forks: the bar may run a thread
            task = bar.add_task(f"methods ({workers} worker processes)", total=len(configs))
            for future in as_completed(futures):
                cfg = configs[futures[future]]
                try:
                    outcomes[futures[future]] = future.result()
                except Exception as exc:  # its worker died (killed, out of memory, a crash in a native library)
                    outcomes[futures[future]] = None, _failure(runs / cfg.name, exc)
                bar.update(task, advance=1, description=f"method {cfg.name} finished")
    return outcomes


def _run_method(cfg: RunConfig, frontend: Frontend, folder: Path, quiet: bool, sweep: bool,
                figures: bool = True) -> Outcome:
    """One method's run files in `folder`, or its error.txt when it fails."""
    try:
        result = run_batch(cfg, frontend, quiet, sweep=sweep)
    except Exception as exc:  # one method's failure must not lose the others' results
        return None, _failure(folder, exc)
    write_run_files(result, folder, figures=figures)
    return result, None


def _failure(folder: Path, exc: BaseException) -> str:
    """error.txt in `folder` with the traceback of `exc`; the line report.md gives the failure."""
    (folder / "error.txt").write_text("".join(traceback.format_exception(exc)))
    return f"{type(exc).__name__}: {exc}"


def _method_in_worker(cfg: RunConfig, folder: Path, sweep: bool, figures: bool = True) -> Outcome:
    """_run_method in a worker, on the front end its parent shares; the result goes back without what only the run
    files needed (the pose graph, which does not pickle, the map and the descriptors: large)."""
    result, error = _run_method(cfg, shared(), folder, True, sweep, figures)
    if result is not None:
        result = replace(result, graph_factors=None, map_points=None, descriptors=None)
    return result, error
