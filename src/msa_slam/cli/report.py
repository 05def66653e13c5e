"""`msa-slam report RESULTS_DIR`: rewrite the report of any msa-slam result folder from the files in it."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

EXPECTED = "a folder written by `msa-slam run`, `online`, `compare`, `demo`, `experiment` or `reproduce`"


def report_command(
    results_dir: Path = typer.Argument(..., help=f"result folder: {EXPECTED}"),
    reference: Optional[str] = typer.Option(
        None,
        help="experiments: the method the memory and ATE differences "
        "compare to (default: the grid's reference, usually all)",
    ),
) -> None:
    """(Re)write a result folder's report.md from its files, without running anything (a comparison's also each
    method's): an experiment's also its results.csv, results.md and figures from the finished cells of its
    current grid.yaml (cells of an earlier grid are listed and left out); a comparison over seeds also its
    seeds.md, seeds.csv and seeds.json."""
    from msa_slam.cli.experiment import echo_stale
    from msa_slam.experiments.rereport import rewrite_folder

    report, stale = rewrite_folder(results_dir, reference, EXPECTED)
    echo_stale(stale)
    typer.echo(str(report))
