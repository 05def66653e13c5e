"""`msa-slam experiment GRID.yaml` and `msa-slam report RESULTS_DIR`."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def experiment_command(
    grid: str = typer.Argument(..., help="grid YAML file, or a shipped preset: table2, ablation, "
                                          "distance_bounds, tiny"),
    scheduler: Optional[str] = typer.Option(None, help="Dask scheduler address (tcp://host:port); the output "
                                                       "folder must be on a file system the workers share"),
    workers: int = typer.Option(1, help="local worker processes (Dask LocalCluster) when no --scheduler"),
    out: Optional[Path] = typer.Option(None, help="results folder (default ./msa_slam_results/experiments/<name>)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Run every unfinished cell of an experiment grid (finished cells are kept and skipped), then write the
    aggregate report; prints the path of its report.md."""
    from msa_slam.experiments.grid import load_grid
    from msa_slam.experiments.runner import run_grid

    spec = load_grid(grid)
    target = out or Path("msa_slam_results") / "experiments" / spec.name
    run = run_grid(spec, target, scheduler=scheduler, workers=workers, quiet=quiet)
    typer.echo(f"{len(run.ran)} cell(s) run, {len(run.skipped)} already finished, {len(run.failed)} failed",
               err=True)
    for cell, error in run.failed.items():
        typer.echo(f"failed: {cell}: {error}", err=True)
    typer.echo(str(target / "report.md"))


def report_command(
    results_dir: Path = typer.Argument(..., help="folder written by `msa-slam experiment`"),
    reference: Optional[str] = typer.Option(None, help="method the memory and ATE differences compare to "
                                                       "(default: the grid's reference, usually all)"),
) -> None:
    """(Re)write results.csv, results.md, figures and report.md from the finished cells of an experiment."""
    from msa_slam.experiments.report import write_report

    typer.echo(str(write_report(results_dir, reference)))
