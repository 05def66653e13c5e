"""`msa-slam report RESULTS_DIR`: rewrite the report of any msa-slam result folder from the files in it."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

EXPECTED = "a folder written by `msa-slam run`, `online`, `compare`, `demo`, `experiment` or `reproduce`"


def report_command(
    results_dir: Path = typer.Argument(..., help=f"result folder: {EXPECTED}"),
    reference: Optional[str] = typer.Option(None, help="experiments: the method the memory and ATE differences "
                                                       "compare to (default: the grid's reference, usually all)"),
) -> None:
    """(Re)write a result folder's report.md from its files, without running anything (a comparison's also each
    method's): an experiment's also its results.csv, results.md and figures from the finished cells of its
    current grid.yaml (cells of an earlier grid are listed and left out); a comparison over seeds also its
    seeds.md, seeds.csv and seeds.json."""
    from msa_slam.errors import InputError
    from msa_slam.experiments.folder import KIND
    from msa_slam.io.marker import result_kind
    from msa_slam.io.outputs import MARKER

    kind = result_kind(results_dir)
    if kind is None:
        outer = next((p for p in Path(results_dir).absolute().parents if result_kind(p) is not None), None)
        inside = f" (it lies inside the result folder {outer}: report that one)" if outer is not None else ""
        raise InputError(f"{results_dir}: not a msa-slam result folder (no {MARKER} written by msa-slam){inside}; "
                         f"expected {EXPECTED}; nothing written")
    if kind == KIND:
        report = _experiment_report(results_dir, reference)
    elif kind == "reproduce":
        from msa_slam.experiments.reproduce import rewrite_reproduce_report

        if reference is not None:
            raise InputError(f"--reference: only for an experiment's folder; {results_dir} is a result of "
                             "`msa-slam reproduce` (its grids' reference is all samples)")
        report = rewrite_reproduce_report(results_dir)
    else:
        from msa_slam.reporting.rereport import KINDS, rewrite_report

        if kind not in KINDS:
            raise InputError(f"{results_dir}: a result of `msa-slam {kind}`, which writes no report.md; expected "
                             f"{EXPECTED}; nothing written")
        if reference is not None:
            raise InputError(f"--reference: only for an experiment's folder; {results_dir} is a result of "
                             f"`msa-slam {kind}`")
        report = rewrite_report(results_dir, kind)
    typer.echo(str(report))


def _experiment_report(results_dir: Path, reference: Optional[str]) -> Path:
    """results.csv, results.md, figures and report.md of an experiment folder, listing its stale cells."""
    from msa_slam.cli.experiment import echo_stale
    from msa_slam.experiments.folder import CELL_FILE, KIND, grid_cells, stale_cells
    from msa_slam.experiments.report import write_report
    from msa_slam.experiments.runner import DEFAULT_PARENT
    from msa_slam.io.outputs import open_result_folder

    with open_result_folder(results_dir, kind=KIND, default_parent=DEFAULT_PARENT, resume=True) as folder:
        folder.prepare_in_place(grows=("cells",), unit_record=CELL_FILE)
        report = write_report(results_dir, reference)
        folder.record_files()
        echo_stale(stale_cells(results_dir, grid_cells(results_dir)[1]))
    return report
