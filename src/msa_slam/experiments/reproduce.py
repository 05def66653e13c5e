"""`msa-slam reproduce`: the paper's evaluation (Tables I and II, the ablations, the distance bounds) by one
command, with a verdict per claim.

Each paper grid (msa_slam.experiments.paper) runs through the experiment runner into grids/<preset>/ of the
output folder, so its cells are cached, resumable and may go to Dask workers exactly as `msa-slam experiment`
sends them; then one report.md (msa_slam.experiments.reproduce_report) and its figures are written beside them.
Every grid, dataset, seed and the scheduler address are checked, and the output folder claimed, before the
first cell runs.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from msa_slam.evaluation.spread import without_rounding
from msa_slam.experiments import paper_claims as pc
from msa_slam.experiments import reproduce_report as rr
from msa_slam.experiments.grid import GridSpec, check_datasets, expand
from msa_slam.experiments.paper import PRESETS, column_of, dataset_name, paper_grids
from msa_slam.experiments.paper_values import grid_values, window_solve_ms
from msa_slam.experiments.rows import CellRow
from msa_slam.io.atomic import write_text_atomic
from msa_slam.io.outputs import DEFAULT_RESULTS, MARKER, open_result_folder
from msa_slam.workers import check_workers

KIND = "reproduce"  # the result-folder kind of msa_slam.io.outputs
DEFAULT_OUT = DEFAULT_RESULTS / "reproduce"
GRIDS = "grids"  # out/grids/<preset>: one experiment folder per paper grid
FIG6_DATASETS = ("kitti-07", "city-tour")  # the paper's Fig. 6 shows MulRan KAIST and Apollo SanJose


@dataclass
class Reproduction:
    """What a reproduce run did: its report, the cells that failed (grid: cell: reason), and how many cells ran,
    were finished earlier, or were copied from an identical cell of this or another grid (experiments.sharing)."""

    report: Path
    failed: dict[str, str] = field(default_factory=dict)
    ran: int = 0
    skipped: int = 0
    shared: int = 0


def run_reproduce(
    presets: Sequence[str],
    quick: bool = False,
    seeds: Sequence[int] | None = None,
    out: str | os.PathLike | None = None,
    scheduler: str | None = None,
    workers: int = 1,
    quiet: bool = True,
    command: str = "msa-slam reproduce",
) -> Reproduction:
    """Run the paper grids `presets` (--quick and --seeds variants: paper.variant) into `out` (default
    msa_slam_results/reproduce, resumed when it holds an earlier reproduction), then write report.md."""
    from msa_slam.experiments.runner import check_scheduler, run_grid

    check_workers(workers)
    if scheduler is not None:
        check_scheduler(scheduler)
    grids = paper_grids(presets, quick, seeds)
    for name, grid in grids.items():
        check_datasets(grid, f"preset {name}", expand(grid, f"preset {name}"))
    started, load = time.monotonic(), os.getloadavg()[0]
    target = Path(out) if out is not None else DEFAULT_OUT
    result = Reproduction(target / "report.md")
    with open_result_folder(target, kind=KIND, default_parent=target.parent, resume=True) as folder:
        folder.prepare_in_place(grows=(GRIDS,), unit_record=MARKER)
        for name, grid in grids.items():
            others = [folder.path / GRIDS / other for other in PRESETS if other != name]
            run = run_grid(
                grid,
                folder.path / GRIDS / name,
                scheduler=scheduler,
                workers=workers,
                quiet=quiet,
                where=f"preset {name}",
                share_from=others,
            )
            result.failed.update({f"{name}: {cell}": why for cell, why in run.failed.items()})
            result.ran, result.skipped = result.ran + len(run.ran), result.skipped + len(run.skipped)
            result.shared += len(run.shared)
        stamp = (
            f"Command: `{command}`; msa-slam {_version()}; {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC; "
            f"wall time {(time.monotonic() - started) / 60:.1f} min on {os.cpu_count()} cores, load average "
            f"{load:.1f} at the start and {os.getloadavg()[0]:.1f} at the end; {result.ran} cell(s) run, "
            f"{result.shared} copied from an identical cell, {result.skipped} reused from an earlier run"
            f"{', quick variant' if quick else ''}."
        )
        write_reproduce_report(folder.path, grids, stamp, result.failed)
        folder.record_files()
    return result


def estimate_reproduction(
    presets: Sequence[str], quick: bool = False, seeds: Sequence[int] | None = None, workers: int = 1
) -> list[str]:
    """What a fresh reproduction of `presets` would cost on `workers` local processes, nothing run: per grid its
    cells, those copied from an identical cell of an earlier grid or of itself, and the estimated time of the
    rest (experiments.estimate: frames times assumed costs a frame, shared work counted once), then the total."""
    from msa_slam.experiments.estimate import duration, estimate_grid
    from msa_slam.experiments.grid import run_key
    from msa_slam.experiments.identity import cell_identities
    from msa_slam.experiments.sharing import plan_sharing

    check_workers(workers)
    lines: list[str] = []
    total, done = 0.0, set[tuple]()
    planned: dict[str, Path] = {}  # run key -> the grid that runs it first
    for name, grid in paper_grids(presets, quick, seeds).items():
        cells = expand(grid, f"preset {name}")
        identities = cell_identities(cells)
        keys = {cell.id: run_key(cell, identities[cell.id]) for cell in cells}
        plan = plan_sharing(cells, keys, planned)
        copies = len(plan.copies) + len(plan.after)
        found = estimate_grid(grid.name, cells, {}, plan.run, workers, shared=copies, done=done)
        planned.update({key: Path(name) for key in keys.values() if key is not None and key not in planned})
        total += found.seconds or 0.0
        lines.append(found.line())
    lines.append(f"all {len(lines)} grid(s): estimated {duration(total)} on {workers} worker(s)")
    return lines


def rewrite_reproduce_report(folder: str | os.PathLike) -> Path:
    """`msa-slam report` of a reproduce folder: report.md and figures again from the finished cells of the grids
    recorded under grids/ (each its grid.yaml as last run), the run's stamp kept and the rewrite noted."""
    from msa_slam.experiments.folder import GRID_FILE, grid_cells

    path = Path(folder)
    with open_result_folder(path, kind=KIND, default_parent=path.parent, resume=True) as result:
        result.prepare_in_place(grows=(GRIDS,), unit_record=MARKER)
        grids = {
            name: grid_cells(path / GRIDS / name)[0] for name in PRESETS if (path / GRIDS / name / GRID_FILE).is_file()
        }
        old = (path / "report.md").read_text() if (path / "report.md").is_file() else ""
        run_stamp = next((line for line in old.splitlines() if line.startswith("Command: ")), "")
        now = f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC"
        stamp = (f"{run_stamp} " if run_stamp else "") + (
            f"Report rewritten by `msa-slam report` (msa-slam {_version()}, {now}) from the finished cells."
        )
        report = write_reproduce_report(path, grids, stamp, {})
        result.record_files()
    return report


def _version() -> str:
    from msa_slam import __version__

    return __version__


def write_reproduce_report(out: Path, grids: dict[str, GridSpec], stamp: str, failed: dict[str, str]) -> Path:
    """report.md and figures/ of `out` from the finished cells of grids/<preset> for each of `grids`."""
    from msa_slam.viz import plot_sweeps, plot_trajectories
    from msa_slam.viz.paper_figures import plot_boxes, plot_memory_distance

    runs = {
        name: rr.Run(grid, grid_values(out / GRIDS / name), f"{GRIDS}/{name}")
        for name, grid in grids.items()
        if (out / GRIDS / name / "cells").is_dir()
    }
    figures = out / "figures"
    figures.mkdir(exist_ok=True)
    t1, t2, ab, bd = (runs.get(p) for p in ("paper-table1", "paper-table2", "paper-ablation", "paper-bounds"))
    t1_figs, t2_figs, bd_figs = [], [], []
    if t1 is not None and t1.values.rows:
        plot_boxes(
            figures / "fig5_deviations.png",
            fig5_panels(t1.values.rows),
            "Table I runs: deviation from all samples (pp: percentage points), memory and time",
            zero_line=list(fig5_panels(t1.values.rows))[:2],
        )
        t1_figs.append("fig5_deviations.png")
        shown = [d for d in dict.fromkeys(r.dataset for r in t1.values.rows) if dataset_name(d) in FIG6_DATASETS]
        for dataset in shown or [t1.values.rows[0].dataset]:
            found = rr.fig6_panels(t1, dataset)
            if found is not None:
                name = f"fig6_{dataset_name(dataset)}.png"
                plot_trajectories(
                    figures / name,
                    found[0],
                    found[1],
                    title=f"{column_of(dataset)} (simulated): MSA and entropy after optimisation",
                )
                t1_figs.append(name)
    growth: dict = {}
    if t2 is not None and t2.values.rows:
        growth, series, drive = rr.memory_growth(t2)
        if series:
            all_gib = list(growth.get("all", {}).values())
            plot_memory_distance(
                figures / "memory_distance.png",
                series,
                (pc.TARGET_M / 1000, sum(all_gib) / len(all_gib)) if all_gib else None,
                pc.LIMIT_GIB,
                f"{column_of(drive)} (simulated): accounted memory over distance",
            )
            t2_figs.append("memory_distance.png")
    if bd is not None and bd.values.rows:
        plot_sweeps(
            figures / "distance_bounds.png",
            sweep_lines(bd.values.rows),
            title="distance bounds: metrics against each bound (means over seeds)",
        )
        bd_figs.append("distance_bounds.png")
    claims = paper_claims(t1, growth, ab, bd, runs)
    lines = [
        "# Reproduction of the paper's evaluation",
        "",
        stamp,
        "",
        "Every dataset is simulated; which paper column each plays:",
        "",
        *rr.stand_in_lines(runs),
    ]
    if failed:
        lines += [
            "Failed cells (their tracebacks: grids/<preset>/errors/):",
            "",
            *(f"- {cell}: {why}" for cell, why in failed.items()),
            "",
        ]
    lines += [
        *rr.table1(t1, t1_figs),
        *rr.table2(t2, t2_figs, growth),
        *rr.ablations(ab),
        *rr.bounds(bd, bd_figs),
        *rr.claims_lines(claims),
    ]
    write_text_atomic(out / "report.md", "\n".join(lines))
    return out / "report.md"


def fig5_panels(rows: list[CellRow]) -> dict[str, dict[str, list[float]]]:
    """The Fig. 5 panels: each method's t./R. ATE improvement minus all samples' on the same run (dataset, mode,
    seed) in percentage points (a difference of rounding alone is 0.0), and its memory and time."""
    panels: dict[str, dict[str, list[float]]] = {
        "t. ATE impr. - all [pp]": {},
        "R. ATE impr. - all [pp]": {},
        "memory [MiB]": {},
        "time [s]": {},
    }
    methods = list(dict.fromkeys(r.method for r in rows))
    for m in methods:
        for title, column in zip(list(panels)[:2], ("improvement_t_pct", "improvement_r_pct")):
            a, b = pc.paired(rows, pc.method(m), pc.method("all"), column)
            if m != "all":
                panels[title][m] = [without_rounding(x, y) for x, y in zip(a, b)]
        panels["memory [MiB]"][m] = [x for r in rows if r.method == m and (x := r.value("memory_mib")) is not None]
        panels["time [s]"][m] = [x for r in rows if r.method == m and (x := r.value("time_s")) is not None]
    return panels


def sweep_lines(rows: list[CellRow]) -> dict:
    """plot_sweeps' input: bound (its axis names the unit) -> metric -> dataset column -> (values, means over seeds)."""
    columns = {
        "t. ATE impr. [%]": "improvement_t_pct",
        "F1-max": "f1_max",
        "memory vs all [%]": "memory_vs_reference_pct",
    }
    out: dict = {}
    for bound in sorted({k for r in rows for k in r.swept}):
        out[bound] = {}
        for title, column in columns.items():
            lines: dict = {}
            for dataset in dict.fromkeys(r.dataset for r in rows):
                points: dict[float, list[float]] = {}
                for r in rows:
                    if r.dataset == dataset and bound in r.swept and (y := r.value(column)) is not None:
                        points.setdefault(float(r.swept[bound]), []).append(y)
                xs = sorted(points)
                lines[column_of(dataset)] = (xs, [sum(points[x]) / len(points[x]) for x in xs])
            out[bound][title] = lines
    return out


def _brief(run: rr.Run | None, what: str) -> str:
    if run is None:
        return f"{what}: not run"
    seeds = sorted({r.seed for r in run.values.rows})
    datasets = ", ".join(dict.fromkeys(column_of(r.dataset) for r in run.values.rows))
    return f"{what}; {run.grid.base.get('odometry', 'kiss')} odometry; {datasets}; seeds {', '.join(map(str, seeds))}"


def paper_claims(
    t1: rr.Run | None, growth: dict, ab: rr.Run | None, bd: rr.Run | None, runs: dict[str, rr.Run]
) -> list[pc.Claim]:
    """The claims table's rows, in the paper's order."""
    rows1 = t1.values.rows if t1 else []
    rows_ab = ab.values.rows if ab else []
    rows_bd = bd.values.rows if bd else []
    drive = f"Table II long drive, all samples and MSA, {len(growth.get('all', {}))} seed(s)"
    solve = [ms for run in runs.values() for ms in window_solve_ms(run.values.cells)]
    constants = list(dict.fromkeys(r.method for r in rows1 if r.method.startswith("constant")))  # --quick: two
    return [
        pc.keeps_accuracy(rows1, _brief(t1, "Table I, oracle, pooled over datasets")),
        pc.best_sampled(rows1, _brief(t1, "Table I, oracle, paired over (dataset, seed)")),
        pc.no_universal_constant(
            rows1, _brief(t1, f"Table I, oracle, {' / '.join(constants) or 'no constant'} per dataset")
        ),
        pc.memory_exhausted(list(growth.get("all", {}).values()), list(growth.get("msa", {}).values()), drive),
        pc.emphasis(
            rows_ab,
            pc.PI_EMPHASIS,
            "Emphasising pi (alpha = 10) raises accuracy and keyframes",
            {"improvement_t_pct": +1, "keyframes": +1},
            _brief(ab, "ablation grid, both scenarios"),
        ),
        pc.emphasis(
            rows_ab,
            pc.RHO_EMPHASIS,
            "Emphasising rho (beta = 10) lowers memory and accuracy",
            {"memory_mib": -1, "improvement_t_pct": -1},
            _brief(ab, "ablation grid, both scenarios"),
        ),
        pc.bound_sweep(rows_bd, "lambda_l", _brief(bd, "bounds grid, lambda_u = 5")),
        pc.bound_sweep(rows_bd, "lambda_u", _brief(bd, "bounds grid, lambda_l = 0.1")),
        pc.window_time(
            solve,
            "every default MSA run (N = 10) of this reproduction; this machine under its load, not the paper's i9",
        ),
    ]
