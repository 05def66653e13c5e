"""`msa-slam reproduce`: the paper's evaluation (Tables I and II, ablations, distance bounds) and a verdict per
claim, in one report.md."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer


def reproduce_command(
    quick: bool = typer.Option(
        False,
        "--quick",
        help="the same grids on short prefixes: fewer datasets, one "
        "seed, Table I in oracle mode only, each sweep at its ends (a smoke run)",
    ),
    out: Optional[Path] = typer.Option(
        None,
        help="results folder: new, empty, or an earlier reproduction's "
        "(resumed) (default: ./msa_slam_results/reproduce)",
    ),
    scheduler: Optional[str] = typer.Option(
        None,
        help="Dask scheduler address (tcp://host:port); the output folder must be on a file system the workers share",
    ),
    workers: int = typer.Option(1, help="local worker processes (Dask LocalCluster) when no --scheduler"),
    seeds: Optional[str] = typer.Option(
        None, help="world seeds of every grid, e.g. 0,1,2 (default: the grids' own, 0,1,2; --quick keeps the first)"
    ),
    presets: Optional[str] = typer.Option(
        None,
        help="the paper grids to run, comma-separated (default: all of "
        "paper-table1, paper-table2, paper-ablation, paper-bounds)",
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
    estimate: bool = typer.Option(
        False,
        "--estimate",
        help="print each grid's cells and estimated time for a fresh run on --workers processes, and run nothing",
    ),
) -> None:
    """Run the paper's evaluation grids (finished cells are kept and skipped), then write one report.md with
    Table I, Table II, the ablations, the distance bounds and a verdict per claim; prints its path. Exits with 1
    when a cell failed."""
    from msa_slam.experiments.paper import parse_presets
    from msa_slam.experiments.reproduce import run_reproduce
    from msa_slam.experiments.seeds import parse_seeds

    if scheduler is not None and workers != 1:
        raise typer.BadParameter("give either --scheduler or --workers, not both", param_hint="--workers")
    names = parse_presets(presets)
    chosen = None if seeds is None else parse_seeds(seeds)
    if estimate:
        from msa_slam.experiments.reproduce import estimate_reproduction

        for line in estimate_reproduction(names, quick=quick, seeds=chosen, workers=workers):
            typer.echo(line)
        return
    run = run_reproduce(
        names,
        quick=quick,
        seeds=chosen,
        out=out,
        scheduler=scheduler,
        workers=workers,
        quiet=quiet,
        command=" ".join(["msa-slam", *sys.argv[1:]]),
    )
    typer.echo(
        f"{run.ran} cell(s) run, {run.shared} copied from an identical cell, {run.skipped} already finished, "
        f"{len(run.failed)} failed",
        err=True,
    )
    for cell, reason in run.failed.items():
        typer.echo(f"failed: {cell}: {reason}", err=True)
    typer.echo(str(run.report))
    if run.failed:
        raise typer.Exit(1)
