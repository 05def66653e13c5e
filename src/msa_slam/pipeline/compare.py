"""The paper's method set on one sequence (Table I): all samples, constant 1/2/3 m, entropy, spaciousness, MSA.

Odometry and descriptors are computed once and shared; each method gets its own run folder under runs/,
and the comparison (Markdown + CSV + figures + report.md) sits at the top of the output folder.
"""

from __future__ import annotations

import os
import traceback
from pathlib import Path
from typing import Any, Sequence

from msa_slam.evaluation import ATE_ALIGNMENT, NA, fmt, notes
from msa_slam.io.outputs import DEFAULT_RESULTS, open_result_folder
from msa_slam.io.tables import mib, rows_csv, write_json
from msa_slam.pipeline.batch import run_batch
from msa_slam.pipeline.config import RunConfig, make_config
from msa_slam.pipeline.frontend import Frontend, prepare_frontend
from msa_slam.pipeline.results import trajectory_panels, write_run_files
from msa_slam.place_recognition.figures import plot_pr_curves
from msa_slam.progress import progress_bar
from msa_slam.slam import RunResult
from msa_slam.viz import plot_metric_bars, plot_trajectories
from msa_slam.viz.labels import display_name

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

COLUMNS = ("method", "keyframes", "candidates", "verified", "false_loops", "ate_before_m", "ate_after_m",
           "improvement_t_pct", "improvement_r_pct", "pr_auc", "f1_max", "memory_mib", "time_s")


def table_row(metrics: dict[str, Any]) -> dict[str, Any]:
    """One Table-I row from a run's metrics (memory: keyframes + graph; time: back-end stages)."""
    m = metrics
    return {
        "method": m["method"], "keyframes": m["keyframes"], "candidates": m["candidates"], "verified": m["verified"],
        "false_loops": m["false_loops"], "ate_before_m": m["before"]["ate_translation_m"],
        "ate_after_m": m["after"]["ate_translation_m"], "improvement_t_pct": m["improvement_pct"]["translation"],
        "improvement_r_pct": m["improvement_pct"]["rotation"], "pr_auc": m["pr_auc"], "f1_max": m["f1_max"],
        "memory_mib": m["memory_bytes"]["total"] / 2**20, "time_s": m["time_s"]["backend_total"],
    }


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return fmt(value, ".3f" if abs(value) < 10 else ".1f")
    return NA if value is None else str(value)


def table_markdown(rows: Sequence[dict[str, Any]]) -> str:
    head = ["method", "keyframes", "candidates", "verified", "false loops", "ATE before [m]", "ATE after [m]",
            "t. ATE impr. [%]", "R. ATE impr. [%]", "PR-AUC", "F1-max", "memory [MiB]", "time [s]"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(_fmt(r[c]) for c in COLUMNS) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _figures(results: Sequence[RunResult], folder: Path) -> list[str]:
    folder.mkdir()
    labels = [r.config.name for r in results]
    rows = [{k: float("nan") if v is None else v for k, v in table_row(r.metrics).items()} for r in results]
    plot_metric_bars(folder / "metrics.png", labels, {
        "ATE translation [m]": {"odometry": [r["ate_before_m"] for r in rows],
                                "optimised": [r["ate_after_m"] for r in rows]},
        "ATE improvement [%]": {"translation": [r["improvement_t_pct"] for r in rows],
                                "rotation": [r["improvement_r_pct"] for r in rows]},
        "memory [MiB]": {"keyframes + graph": [r["memory_mib"] for r in rows]},
        "back-end time [s]": {"time": [r["time_s"] for r in rows]},
    }, title=f"{display_name(results[0].metrics['sequence'])} ({results[0].config.mode} loops)")
    gt_xy = results[0].gt_poses[:, :2, 3]
    panels = [trajectory_panels(r)[1] for r in results]
    plot_trajectories(folder / "trajectories.png", gt_xy, [trajectory_panels(results[0])[0], *panels],
                      title=f"{display_name(results[0].metrics['sequence'])}: keyframe trajectories of every sampler "
                      "after optimisation, coloured by ATE", columns=4)
    curves = {r.config.name: r.pr for r in results if r.pr is not None and r.pr.auc is not None}
    names = ["metrics.png", "trajectories.png"]
    if curves:
        plot_pr_curves(curves, folder / "pr_curves.png",
                       title=f"{display_name(results[0].metrics['sequence'])}: loop candidates per method")
        names.append("pr_curves.png")
    return names


def _report(fe: Frontend, results: Sequence[RunResult], table: str, figures: list[str]) -> str:
    cfg = results[0].config
    cached = " (from cache)" if all(fe.cached.values()) else ""
    front = ", ".join(f"{k} {v:.1f} s" for k, v in fe.timer.seconds.items())
    lines = [f"# Sampler comparison on {fe.name}", "",
             f"Dataset `{cfg.dataset}`: {len(fe)} frames. Odometry `{cfg.odometry}`, descriptor `{cfg.descriptor}`, "
             f"loops: similarity >= {cfg.similarity_threshold}, {cfg.mode} verification (small_gicp residual < "
             f"{cfg.verifier.max_residual} m), GTSAM Levenberg-Marquardt. Shared front end: {front}{cached}.", "",
             f"ATE: keyframe trajectory vs ground truth after {ATE_ALIGNMENT} alignment (fitted on all keyframes of "
             "each estimate), before (odometry) and after pose-graph optimisation; improvement = 100 (before - "
             "after) / before. False loops: verified loops whose ground-truth distance exceeds "
             f"{cfg.loop_radius} m. Memory: accounted bytes of keyframe descriptors, downsampled keyframe clouds "
             "and the graph, per method. Time: sampling + keyframe store + loop search + verification + "
             "optimisation.", "", table, "",
             f"Process peak RSS: {mib(max(r.metrics['peak_rss_bytes'] for r in results))} (whole process: "
             "every method and the shared front end; not a per-method figure).", ""]
    method_notes = [f"- {r.config.name}: {note}" for r in results for note in notes(r.metrics)]
    if method_notes:
        lines += ["Notes (n/a values and warnings):", "", *method_notes, ""]
    lines += [f"![{n}](figures/{n})" for n in figures]
    lines += ["", "Per-method results: " + ", ".join(f"[{r.config.name}](runs/{r.config.name}/report.md)"
                                                  for r in results), ""]
    return "\n".join(lines)


def method_configs(base: RunConfig, methods: Sequence[tuple[str, str, dict[str, Any]]] = PAPER_METHODS
                   ) -> list[RunConfig]:
    """One validated config per method: `base` with the method's sampler, parameters and label."""
    data = base.dump()
    return [make_config({**data, "sampler": s, "sampler_params": p, "label": label}) for label, s, p in methods]


class MethodsFailed(Exception):
    """Some methods of a comparison failed; the others' results were written (`report`), the failures listed."""

    def __init__(self, report: Path, failed: dict[str, str]) -> None:
        super().__init__(f"{len(failed)} method(s) failed: " + "; ".join(f"{k}: {v}" for k, v in failed.items()))
        self.report, self.failed = report, failed


def run_compare(base: RunConfig, out: str | os.PathLike | None, quiet: bool = True,
                methods: Sequence[tuple[str, str, dict[str, Any]]] = PAPER_METHODS, overwrite: bool = False,
                default_parent: Path = DEFAULT_RESULTS / "compare") -> Path:
    """Run every method on the sequence of `base` and write the comparison folder; return its report.md.

    `out` is checked before any work (msa_slam.io.outputs; None: a new timestamped folder under
    `default_parent`) and appears only when complete. A method that fails does not cost the others: the
    folder is written with the methods that finished, the failed ones are marked in report.md (their
    traceback in runs/<method>/error.txt), and MethodsFailed is raised afterwards.
    """
    configs = method_configs(base, methods)
    with open_result_folder(out, "compare", default_parent, overwrite=overwrite) as folder:
        frontend = prepare_frontend(configs[0], quiet)
        with folder.staging() as tmp:
            results, failed = _run_methods(configs, frontend, tmp / "runs", quiet)
            rows = [table_row(r.metrics) for r in results]
            table = table_markdown(rows)
            (tmp / "comparison.md").write_text(table)
            (tmp / "comparison.csv").write_text(rows_csv(rows, COLUMNS))
            write_json(tmp / "comparison.json", [r.metrics for r in results])
            figures = _figures(results, tmp / "figures") if results else []
            report = (_report(frontend, results, table, figures) if results
                      else f"# Sampler comparison on {frontend.name}\n")
            if failed:
                report += "\n## Failed methods\n\n" + "".join(f"- {name}: {error} (traceback: runs/{name}/error.txt)\n"
                                                         for name, error in failed.items())
            (tmp / "report.md").write_text(report)
    if failed:
        raise MethodsFailed(folder.path / "report.md", failed)
    return folder.path / "report.md"


def _run_methods(configs: Sequence[RunConfig], frontend, runs: Path, quiet: bool
                 ) -> tuple[list[RunResult], dict[str, str]]:
    """Each method's run folder under `runs`, in order; a failing method leaves its error.txt instead."""
    runs.mkdir()
    results, failed = [], {}
    with progress_bar(quiet, transient=False) as bar:
        task = bar.add_task("methods", total=len(configs))
        for cfg in configs:
            bar.update(task, description=f"method {cfg.name}")
            (runs / cfg.name).mkdir()
            try:
                result = run_batch(cfg, frontend, quiet)
            except Exception as exc:  # one method's failure must not lose the others' results
                (runs / cfg.name / "error.txt").write_text("".join(traceback.format_exception(exc)))
                failed[cfg.name] = f"{type(exc).__name__}: {exc}"
            else:
                write_run_files(result, runs / cfg.name)
                results.append(result)
            bar.advance(task)
    return results, failed
