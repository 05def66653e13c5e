"""The paper's method set on one sequence (Table I): all samples, constant 1/2/3 m, entropy, spaciousness, MSA.

Odometry and descriptors are computed once and shared; each method gets its own run folder under runs/,
and the comparison (Markdown + CSV + figures + report.md: reporting.comparison) sits at the top of the output
folder.
"""

from __future__ import annotations

import logging
import os
import sys
import traceback
from collections.abc import Mapping, Sequence
from concurrent.futures import as_completed
from dataclasses import replace
from pathlib import Path
from typing import Any

from msa_slam.errors import InputError
from msa_slam.evaluation import peak_rss_bytes
from msa_slam.evaluation.metrics_writer import to_json
from msa_slam.evaluation.run_metrics import ComparisonRow
from msa_slam.experiments.seed_folder import (
    RECORD,
    check_seed_folder,
    clean_leftovers,
    finished_metrics,
    left_out_seeds,
    remove_seeds,
    resume_seeds,
    seed_dir,
    seed_identities,
    seed_record,
    write_record,
)
from msa_slam.experiments.seeds import SEED_COLUMNS, seed_markdown, seed_rows, seed_summary, seeded_datasets
from msa_slam.experiments.sweep import threshold_sweep
from msa_slam.io.atomic import atomic_path, write_text_atomic
from msa_slam.io.outputs import DEFAULT_RESULTS, open_result_folder, staged_dir
from msa_slam.io.tables import mib, rows_csv, write_json
from msa_slam.pipeline.config import RunConfig, make_config
from msa_slam.pipeline.driver import run
from msa_slam.pipeline.frontend import CONFIG_WINDOW_FIX, CachedFrontEnd, prepare_frontend
from msa_slam.progress import progress_bar
from msa_slam.reporting.comparison import (
    COLUMNS,
    PROCESSES,
    comparison_report,
    failed_section,
    table_markdown,
    table_row,
    write_figures,
)
from msa_slam.reporting.results import write_run_files
from msa_slam.reporting.sequence_text import rpe_segments, scans_read
from msa_slam.sampling.params import GATE_PARAMETERS
from msa_slam.slam import RunResult
from msa_slam.slam.build import UNGATED_SAMPLERS
from msa_slam.viz.labels import display_name
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
UNDER_STUDY = "msa"  # the sampler that gets the user's sampler parameters (method_configs)


def method_configs(
    base: RunConfig, methods: Sequence[tuple[str, str, dict[str, Any]]] = PAPER_METHODS
) -> list[RunConfig]:
    """One validated config per method: `base` with the method's sampler, parameters and label.

    When `base` is a config of the sampler under study (UNDER_STUDY), its sampler parameters (-p window=8,
    -p sampler.lambda_u=5) go to every method of that sampler, under the method's own, so compare measures
    the MSA the user asked for; the baselines keep the paper's settings (check_compare_sampler refuses
    parameters given for another sampler, which would have nowhere to go). The standstill gate's parameters
    (min_motion, min_rotation) are the exception: they go to every method but those the SLAM core leaves ungated
    ("all"), so that all methods are compared on the same frames."""
    data = base.dump()
    given: Mapping[str, Any] = base.sampler_params if base.sampler == UNDER_STUDY else {}
    gate = {k: v for k, v in given.items() if k in GATE_PARAMETERS}

    def params_of(sampler: str, params: dict[str, Any]) -> dict[str, Any]:
        if sampler == UNDER_STUDY:
            return {**given, **params}
        return params if sampler in UNGATED_SAMPLERS else {**gate, **params}

    return [
        make_config({**data, "sampler": sampler, "sampler_params": params_of(sampler, params), "label": label})
        for label, sampler, params in methods
    ]


def check_compare_sampler(base: RunConfig) -> None:
    """compare runs the paper's methods and gives the sampler parameters to MSA: parameters given for another
    sampler (-p sampler=constant -p distance=2) would be dropped without a word, so they are refused."""
    if base.sampler != UNDER_STUDY and base.sampler_params:
        given = ", ".join(f"{k}={v!r}" for k, v in base.sampler_params.items())
        raise InputError(
            f"compare: the sampler parameters go to {UNDER_STUDY} (the baselines keep the paper's "
            f"settings); {given} are for sampler {base.sampler!r}: drop them, or give them to "
            f"`msa-slam run -p sampler={base.sampler}`"
        )


class MethodsFailed(Exception):
    """Some methods of a comparison failed; the others' results were written (`report`), the failures listed."""

    def __init__(self, report: Path, failed: dict[str, str]) -> None:
        super().__init__(f"{len(failed)} method(s) failed: " + "; ".join(f"{k}: {v}" for k, v in failed.items()))
        self.report, self.failed = report, failed


def run_compare(
    base: RunConfig,
    out: str | os.PathLike | None,
    quiet: bool = True,
    methods: Sequence[tuple[str, str, dict[str, Any]]] = PAPER_METHODS,
    overwrite: bool = False,
    default_parent: Path = DEFAULT_RESULTS / "compare",
    seeds: Sequence[int] | None = None,
    sweep: bool = True,
    window_fix: str = CONFIG_WINDOW_FIX,
    workers: int = 1,
    figures: bool = True,
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
    changed since (msa_slam.experiments.seed_folder); `overwrite` starts afresh.

    `sweep=False` leaves out each method's threshold sweep (experiments/sweep.py), about half of a method's time;
    `figures=False` the PNG figures (the comparison's and each method's, most of a short comparison's time):
    the tables and data files are the same. It is no setting a resumed seed must match.
    A method whose sampler window the frames read never fill is refused before the shared front end
    (prepare_frontend; `window_fix`: what the error says to change).

    `workers` > 1 runs the methods (of each seed) in that many worker processes forked from this one after the
    front end (_run_methods, msa_slam.workers); the files are byte for byte those of a serial run, but for the
    measured times and memory.
    """
    check_workers(workers)
    plans = (
        None
        if seeds is None
        else {
            seed: method_configs(make_config({**base.dump(), "dataset": dataset}), methods)
            for seed, dataset in zip(seeds, seeded_datasets(base.dataset, seeds))
        }
    )
    with open_result_folder(out, "compare", default_parent, overwrite=overwrite, resume=plans is not None) as folder:
        if plans is None:
            with folder.staging() as tmp:
                _, failed = _comparison(method_configs(base, methods), tmp, quiet, sweep, window_fix, workers, figures)
        else:
            if not overwrite:
                check_seed_folder(folder.path)
            grown = folder.prepare_in_place(fresh=overwrite, grows=("seeds",), unit_record=RECORD)
            failed = _seed_comparisons(base, plans, grown, quiet, sweep, window_fix, workers, figures)
            folder.record_files()
    if failed:
        raise MethodsFailed(folder.path / "report.md", failed)
    return folder.path / "report.md"


def _comparison(
    configs: Sequence[RunConfig],
    tmp: Path,
    quiet: bool,
    sweep: bool,
    window_fix: str,
    workers: int,
    figures: bool = True,
) -> tuple[list[ComparisonRow], dict[str, str]]:
    """One comparison folder's files in `tmp` (the methods in `workers` processes); its table rows and failed
    methods."""
    workers = min(workers, len(configs))  # no idle workers
    frontend = prepare_frontend(configs[0], quiet, configs, window_fix)
    results, failed = _run_methods(configs, frontend, tmp / "runs", quiet, sweep, workers, figures)
    rows = [table_row(r.measured) for r in results]
    table = table_markdown(rows, rpe_segments(results[0].gt_poses)[0] if results else "KITTI segments")
    (tmp / "comparison.md").write_text(table)
    (tmp / "comparison.csv").write_text(rows_csv([r.record() for r in rows], COLUMNS))
    write_json(tmp / "comparison.json", [to_json(r.measured) for r in results])
    drawn = write_figures(results, tmp / "figures", failed, figures) if results else []
    main_peak = mib(peak_rss_bytes())
    write_json(tmp / PROCESSES, {"workers": workers, "main_peak_rss": main_peak})
    report = (
        comparison_report(frontend, results, table, drawn, workers, main_peak)
        if results
        else f"# Sampler comparison on {display_name(frontend.name)}\n"
    )
    (tmp / "report.md").write_text(report + failed_section(failed))
    return rows, failed


def _seed_comparisons(
    base: RunConfig,
    plans: dict[int, list[RunConfig]],
    out: Path,
    quiet: bool,
    sweep: bool,
    window_fix: str,
    workers: int,
    figures: bool = True,
) -> dict[str, str]:
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


def write_spread(
    out: Path,
    base: RunConfig,
    rows: dict[int, list[ComparisonRow]],
    failed: dict[str, str],
    left_out: list[int],
    rerun: Sequence[str] = (),
) -> None:
    """seeds.md, seeds.csv, seeds.json and report.md at the top of `out`, each replaced atomically; `rerun`: the
    lines of the seeds this run reran because their data or code changed, listed in report.md."""
    summary = seed_summary(rows)
    table = seed_markdown(summary)
    write_text_atomic(out / "seeds.md", table)
    write_text_atomic(out / "seeds.csv", rows_csv(seed_rows(summary), SEED_COLUMNS))
    with atomic_path(out / "seeds.json") as path:
        write_json(path, summary.to_json())
    lines = [
        f"# Sampler comparison over world seeds: `{base.dataset}`",
        "",
        "Each seed simulates a different world along the same trajectory; every seed's full comparison "
        "(table, figures, per-method runs) is under seeds/seed-<n>/. Metrics as in those reports (ATE and "
        f"improvement on the full-rate trajectory). Scans read on every seed: {scans_read(base.source)}.",
        "",
        table,
    ]
    lines += [f"- [seed {s}](seeds/seed-{s}/report.md)" for s in rows]
    if left_out:
        lines += [
            "",
            "Also in seeds/, left out of the spread (not among --seeds): "
            + ", ".join(f"[seed {s}](seeds/seed-{s}/report.md)" for s in left_out),
        ]
    if rerun:
        lines += ["", "Seeds rerun by this run, their earlier results replaced:", "", *(f"- {line}" for line in rerun)]
    if failed:
        lines += ["", "## Failed methods", "", *(f"- {k}: {v}" for k, v in failed.items())]
    write_text_atomic(out / "report.md", "\n".join(lines) + "\n")


Outcome = tuple[RunResult | None, str | None]  # a method's result, or None and the line saying why it failed


def _run_methods(
    configs: Sequence[RunConfig],
    frontend: CachedFrontEnd,
    runs: Path,
    quiet: bool,
    sweep: bool,
    workers: int = 1,
    figures: bool = True,
) -> tuple[list[RunResult], dict[str, str]]:
    """Each method's run folder under `runs` (a failing method leaves its error.txt instead); the results and the
    failures, both in method order. With `workers` > 1 the methods run in that many processes forked from this
    one (msa_slam.workers: they share the front end), each running its methods one after another."""
    runs.mkdir()
    for cfg in configs:
        (runs / cfg.name).mkdir()
    outcomes = (
        _serial(configs, frontend, runs, quiet, sweep, figures)
        if workers == 1
        else _parallel(configs, frontend, runs, quiet, sweep, workers, figures)
    )
    results = [result for result, _ in outcomes if result is not None]
    failed = {cfg.name: error for cfg, (_, error) in zip(configs, outcomes) if error is not None}
    return results, failed


def _serial(
    configs: Sequence[RunConfig], frontend: CachedFrontEnd, runs: Path, quiet: bool, sweep: bool, figures: bool = True
) -> list[Outcome]:
    """The methods one after another in this process, each showing its back-end's progress."""
    outcomes = []
    with progress_bar(quiet, transient=False) as bar:
        task = bar.add_task("methods", total=len(configs))
        for cfg in configs:
            bar.update(task, description=f"method {cfg.name}")
            outcomes.append(_run_method(cfg, frontend, runs / cfg.name, quiet, sweep, figures))
            bar.advance(task)
    return outcomes


def _parallel(
    configs: Sequence[RunConfig],
    frontend: CachedFrontEnd,
    runs: Path,
    quiet: bool,
    sweep: bool,
    workers: int,
    figures: bool = True,
) -> list[Outcome]:
    """The methods in `workers` forked processes; one bar, advancing as methods finish (in whatever order)."""
    outcomes: list[Outcome] = [(None, None)] * len(configs)
    with forked_workers(workers, frontend) as submit:
        futures = {submit(_method_in_worker, cfg, runs / cfg.name, sweep, figures): i for i, cfg in enumerate(configs)}
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


def _run_method(
    cfg: RunConfig, frontend: CachedFrontEnd, folder: Path, quiet: bool, sweep: bool, figures: bool = True
) -> Outcome:
    """One method's run files in `folder`, or its error.txt when it fails."""
    try:
        result = run(cfg, frontend, quiet, sweep=threshold_sweep if sweep else None)
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
