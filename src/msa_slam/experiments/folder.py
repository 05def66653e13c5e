"""Layout of an experiment results folder and what belongs to its report.

.msa-slam-result          marker (msa_slam.io.outputs): the folder was written by `msa-slam experiment`
grid.yaml                 the grid as last run: the only cells reported are the ones it expands to
cells/<cell id>/          one finished run per cell (cell.json, metrics.json, ...); ids hash the config,
                          so a cell left by an earlier, different grid is recognised as stale; cell.json
                          records the identity of the cell's data and code, and a resume reruns a cell
                          whose data or code changed since (msa_slam.experiments.identity)
errors/<cell id>.txt      the traceback of a cell that failed (removed when it later succeeds)
results.csv, results.md, figures/, report.md    the aggregate (msa_slam.experiments.report, grid_figures)

The cells are read back here (read_cell, load_cells; an online cell's steps.csv: read_steps) for the report,
a resume and the paper's figures.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from msa_slam.errors import InputError
from msa_slam.evaluation.metrics_json import from_json
from msa_slam.evaluation.run_metrics import RunMetrics
from msa_slam.experiments.cell_info import CellRecord
from msa_slam.experiments.grid import Cell, GridSpec, expand, parse_grid
from msa_slam.io.atomic import write_text_atomic
from msa_slam.io.yaml_file import read_yaml

logger = logging.getLogger(__name__)

KIND = "experiment"  # the result-folder kind of msa_slam.io.outputs
GRID_FILE = "grid.yaml"
CELL_FILE = "cell.json"
METRICS_FILE = "metrics.json"


@dataclass(frozen=True)
class FinishedCell:
    """A finished cell of the grid: what it ran (cell.json), its report and its folder."""

    info: CellRecord
    metrics: RunMetrics
    folder: Path


def cell_dir(out: str | os.PathLike, cell_id: str) -> Path:
    return Path(out) / "cells" / cell_id


def read_cell(folder: Path) -> FinishedCell | None:
    """The finished cell in `folder`; None when cell.json or metrics.json is missing or unreadable, cell.json is of
    another cell, or either lacks a key or holds a wrong type (logged, naming the file and key): a corrupt cell
    counts as unfinished and is rerun, never silently dropped."""
    try:
        info = json.loads((folder / CELL_FILE).read_text())
        data = json.loads((folder / METRICS_FILE).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(info, dict) or info.get("id") != folder.name:
        return None
    try:
        return FinishedCell(
            CellRecord.from_json(info, str(folder / CELL_FILE)), from_json(data, str(folder / METRICS_FILE)), folder
        )
    except InputError as exc:
        logger.warning("%s; the cell counts as unfinished", exc)
        return None


FinishedCells = dict[str, FinishedCell]  # cell id -> the finished cell


def finished_cells(out: str | os.PathLike, cells: list[Cell]) -> FinishedCells:
    """The finished cells of `cells` in `out`, each read once (read_cell): a resume checks their identity,
    skips them and reports them from this one reading."""
    found = {cell.id: read_cell(cell_dir(out, cell.id)) for cell in cells}
    return {cell_id: read for cell_id, read in found.items() if read is not None}


def write_grid(out: Path, grid: GridSpec) -> None:
    write_text_atomic(out / GRID_FILE, yaml.safe_dump(grid.model_dump(mode="json"), sort_keys=False))


def grid_cells(out: str | os.PathLike) -> tuple[GridSpec, list[Cell]]:
    """The grid recorded in `out` and its cells (the cells a report of `out` may use)."""
    path = Path(out) / GRID_FILE
    try:
        data = read_yaml(path)
    except OSError as exc:
        raise InputError(
            f"{path}: cannot read the experiment's grid ({exc.strerror}); rerun `msa-slam experiment` into this folder"
        ) from None
    grid = parse_grid(data, str(path))
    return grid, expand(grid, str(path))


def stale_cells(out: str | os.PathLike, cells: list[Cell]) -> list[str]:
    """Ids of cell folders in `out` that the current grid does not contain (left by an earlier grid). Only
    folders msa-slam wrote count, those with a cell.json (a cell folder appears only once complete): a
    person's own folder under cells/ is no cell, stale or not, and is neither listed nor touched."""
    folder = Path(out) / "cells"
    if not folder.is_dir():
        return []
    current = {c.id for c in cells}
    return sorted(
        p.name
        for p in folder.iterdir()
        if p.is_dir() and not p.name.startswith(".") and p.name not in current and (p / CELL_FILE).is_file()
    )


def load_cells(results_dir: str | os.PathLike) -> list[FinishedCell]:
    """(cell info + metrics) of every finished cell of the grid recorded in `results_dir` (grid.yaml), in the
    grid's order; cell folders of an earlier, different grid are left out (see `stale_cells`)."""
    return finished_list(Path(results_dir), experiment_grid(Path(results_dir))[1])


def experiment_grid(out: Path) -> tuple[GridSpec, list[Cell]]:
    """The grid recorded in the experiment folder `out` and its cells; refuses a folder that is none."""
    if not (out / "cells").is_dir():
        raise InputError(f"{out}: not an experiment results folder (no cells/ inside)")
    return grid_cells(out)


def finished_list(out: Path, cells: list[Cell], known: FinishedCells | None = None) -> list[FinishedCell]:
    """The finished ones of `cells` in `out`, in their order, taken from `known` (already read) where it has them."""
    found = []
    for cell in cells:
        read = (known or {}).get(cell.id) or read_cell(cell_dir(out, cell.id))
        if read is not None:  # its place in this grid, which an earlier grid's may differ from
            found.append(replace(read, info=replace(read.info, index=cell.index)))
    return found


def read_steps(folder: Path) -> dict[str, np.ndarray] | None:
    """The per-step record (steps.csv) of an online cell by column; None for a cell without one (batch)."""
    path = folder / "steps.csv"
    if not path.is_file():
        return None
    data = np.genfromtxt(path, delimiter=",", names=True)
    names = data.dtype.names
    assert names is not None, "genfromtxt names the columns of a file read with names=True"
    return {name: np.atleast_1d(data[name]) for name in names}
