"""What a cell's results depend on besides its config: the content of its input data and msa-slam's code.

A cell's id hashes its config only, so a resume after the dataset's scans (or a file the config names, e.g. a
pose file or network weights) or the code changed would otherwise report old cells beside new ones. Each cell
records {"data": ..., "code": ...} in its cell.json (CELL_IDENTITY); a resume reruns the finished cells whose
record differs from the current one. How the identities are computed, and why so: msa_slam.pipeline.identity
(shared with `compare --seeds`).
"""

from __future__ import annotations

from msa_slam.experiments.folder import FinishedCells
from msa_slam.experiments.grid import Cell
from msa_slam.pipeline.identity import changed_identity, run_identities

CELL_IDENTITY = "identity"  # the key of cell.json that records it


def cell_identities(cells: list[Cell]) -> dict[str, dict[str, str | None]]:
    """{"data": ..., "code": ...} of every cell by id; "data" is None when the dataset cannot be opened now (the
    cell then fails when it runs, with the reason). Each dataset selection is opened once."""
    return run_identities({cell.id: [cell.config] for cell in cells})


def outdated_cells(finished: FinishedCells, identities: dict[str, dict[str, str | None]]) -> dict[str, str]:
    """The `finished` cells whose recorded identity differs from `identities` (cell_identities), each with the
    line that says why it is rerun."""
    out = {}
    for cell_id, (info, _) in finished.items():
        reason = changed_identity(info.get(CELL_IDENTITY), identities[cell_id])
        if reason is not None:
            out[cell_id] = f"cell {cell_id}: {reason}; rerun"
    return out
