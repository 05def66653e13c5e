"""Cells that compute the same run (the same grid.run_key: config as run, data and code) run once.

The paper's grids repeat runs: all samples and default MSA on the Table II scenarios appear in Table II, the
ablation and the distance-bound sweep, and a sweep's point can equal another sweep's. A cell whose run key
matches a finished cell (of this experiment folder or of the `share_from` folders, e.g. the other grids of a
reproduction) or an earlier cell of the same run is not run again: its folder is a copy of that cell's, and
its cell.json (its own info, identity and run key) records where the files came from (`shared_from`), a
path relative to the cell's folder. The copied files are the other cell's (their label is that cell's).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from msa_slam.experiments.cell_info import CellRecord
from msa_slam.experiments.folder import CELL_FILE, cell_dir, read_cell
from msa_slam.experiments.grid import Cell
from msa_slam.io.staging import staged_dir
from msa_slam.io.tables import write_json


@dataclass
class SharePlan:
    """Which cells to run and which to copy: `copies` maps a cell id to the finished folder it copies, `after`
    a cell id to the cell of this run it copies once that one has finished."""

    run: list[Cell] = field(default_factory=list)
    copies: dict[str, Path] = field(default_factory=dict)
    after: dict[str, str] = field(default_factory=dict)


def finished_runs(folders: Sequence[Path]) -> dict[str, Path]:
    """Run key -> folder of a finished cell that recorded it, over the cells/ of every experiment folder of
    `folders` (the first found wins; a copy is as good as its source)."""
    out: dict[str, Path] = {}
    for folder in folders:
        cells = Path(folder) / "cells"
        if not cells.is_dir():
            continue
        for cell in sorted(cells.iterdir()):
            read = read_cell(cell) if cell.is_dir() and not cell.name.startswith(".") else None
            if read is not None and read.info.run_key is not None:
                out.setdefault(read.info.run_key, cell)
    return out


def plan_sharing(todo: Sequence[Cell], keys: Mapping[str, str | None], finished: Mapping[str, Path]) -> SharePlan:
    """Split `todo` (keys: run key by cell id) into cells to run and copies of a `finished` cell (finished_runs)
    or of the first cell of `todo` with the same key."""
    plan = SharePlan()
    first: dict[str, str] = {}
    for cell in todo:
        key = keys.get(cell.id)
        if key is not None and key in finished:
            plan.copies[cell.id] = finished[key]
        elif key is not None and key in first:
            plan.after[cell.id] = first[key]
        else:
            if key is not None:
                first[key] = cell.id
            plan.run.append(cell)
    return plan


def copy_cell(source: Path, out: Path, info: CellRecord) -> None:
    """The cell `info.id` of the experiment `out` as a copy of the finished cell folder `source`, written
    atomically, with `info` and where its files came from as its cell.json."""
    target = cell_dir(out, info.id)
    with staged_dir(target) as tmp:
        for item in sorted(source.iterdir()):
            if item.name == CELL_FILE or item.name.startswith("."):  # its own cell.json; a writer's lock file
                continue
            if item.is_dir():
                shutil.copytree(item, tmp / item.name)
            else:
                shutil.copy2(item, tmp / item.name)
        shared_from = os.path.relpath(source.resolve(), target.resolve())
        write_json(tmp / CELL_FILE, replace(info, shared_from=shared_from).to_json())
