"""`msa-slam report RESULTS_DIR`: rewrite an experiment's aggregate tables, figures and report."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def report_command(
    results_dir: Path = typer.Argument(..., help="folder written by `msa-slam experiment`"),
    reference: Optional[str] = typer.Option(None, help="method the memory and ATE differences compare to "
                                                       "(default: the grid's reference, usually all)"),
) -> None:
    """(Re)write results.csv, results.md, figures and report.md from the finished cells of the experiment's
    current grid.yaml (cells of an earlier grid are listed and left out)."""
    from msa_slam.cli.experiment import echo_stale
    from msa_slam.errors import InputError
    from msa_slam.experiments.folder import CELL_FILE, KIND, grid_cells, stale_cells
    from msa_slam.experiments.report import write_report
    from msa_slam.experiments.runner import DEFAULT_PARENT
    from msa_slam.io.outputs import MARKER, is_result_folder, open_result_folder

    if not is_result_folder(results_dir, KIND):
        raise InputError(f"{results_dir}: not a folder written by `msa-slam experiment` (no {MARKER} of an "
                         "experiment); nothing written")
    with open_result_folder(results_dir, kind=KIND, default_parent=DEFAULT_PARENT, resume=True) as folder:
        folder.prepare_in_place(grows=("cells",), unit_record=CELL_FILE)
        report = write_report(results_dir, reference)
        folder.record_files()
        echo_stale(stale_cells(results_dir, grid_cells(results_dir)[1]))
    typer.echo(str(report))
