"""`msa-slam experiment GRID.yaml`: every unfinished cell of a grid, then the aggregate report."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def experiment_command(
    grid: str = typer.Argument(
        ..., help="grid YAML file, or a shipped preset: table2, ablation, distance_bounds, tiny"
    ),
    scheduler: Optional[str] = typer.Option(
        None,
        help="Dask scheduler address (tcp://host:port); the output folder must be on a file system the workers share",
    ),
    workers: int = typer.Option(1, help="local worker processes (Dask LocalCluster) when no --scheduler"),
    out: Optional[Path] = typer.Option(
        None,
        help="results folder: new, empty, or a previous experiment's "
        "(resumed) (default: a new ./msa_slam_results/experiments/"
        "<timestamp>, linked as latest)",
    ),
    overwrite: bool = typer.Option(
        False,
        "--overwrite",
        help="replace a previous result in --out instead of resuming it (its finished cells are discarded)",
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Run every unfinished cell of an experiment grid (finished cells are kept and skipped), then write the
    aggregate report; prints the path of its report.md. Exits with 1 when a cell failed."""
    from msa_slam.experiments.grid import load_grid
    from msa_slam.experiments.runner import run_grid

    run = run_grid(
        load_grid(grid), out, scheduler=scheduler, workers=workers, quiet=quiet, overwrite=overwrite, where=grid
    )
    rerun = f" ({len(run.rerun)} rerun: their data or code changed)" if run.rerun else ""
    shared = f", {len(run.shared)} copied from an identical cell" if run.shared else ""
    typer.echo(
        f"{len(run.ran)} cell(s) run{rerun}{shared}, {len(run.skipped)} already finished, {len(run.failed)} failed",
        err=True,
    )
    echo_stale(run.stale)
    for cell, reason in run.failed.items():
        typer.echo(f"failed: {cell}: {reason} (traceback: {run.out / 'errors' / (cell + '.txt')})", err=True)
    typer.echo(str(run.report))
    if run.failed:
        raise typer.Exit(1)


def echo_stale(stale: list[str]) -> None:
    """One stderr line listing the cells of an earlier grid that the aggregates leave out."""
    if stale:
        typer.echo(
            f"{len(stale)} stale cell(s) from an earlier grid, left out of the report: " + ", ".join(stale), err=True
        )
