"""Every read of a finished grid's cells that `reproduce` needs, in one place: the flat rows of
experiments.report.make_rows, the MSA window solve times, the memory-over-distance series and the aligned
trajectories of Fig. 6. Only this module
walks a cell's metrics or files, so that a change of their layout is met here alone."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msa_slam.errors import InputError
from msa_slam.experiments.folder import FinishedCell, load_cells, read_steps
from msa_slam.experiments.report import make_rows
from msa_slam.experiments.rows import CellRow
from msa_slam.reporting.results import accounted_bytes


@dataclass(frozen=True)
class GridValues:
    """The finished cells of one grid: make_rows' rows and the cells themselves."""

    rows: list[CellRow]
    cells: list[FinishedCell]


def grid_values(folder: str | Path, reference: str = "all") -> GridValues:
    """Rows of every finished cell of the experiment folder `folder` (with their `mode` and `swept` values), and the
    cells."""
    cells = load_cells(folder)
    return GridValues(make_rows(cells, reference), cells)


def window_solve_ms(cells: list[FinishedCell], method: str = "msa") -> list[float]:
    """Median time of one window optimisation of each `method` cell (its sampler_stats), in ms."""
    out = []
    for cell in cells:
        median = (cell.metrics.sampler_stats or {}).get("optimisation_ms_median")
        if cell.info.method == method and isinstance(median, (int, float)):
            out.append(float(median))
    return out


def memory_over_distance(cell: FinishedCell) -> tuple[np.ndarray, np.ndarray] | None:
    """(ground-truth path length [m], accounted memory [bytes]) at every frame of an online cell; None when the
    cell kept no per-step record."""
    steps = read_steps(cell.folder)
    frames_csv = cell.folder / "frames.csv"
    if steps is None or not frames_csv.is_file():
        return None
    frames = np.genfromtxt(frames_csv, delimiter=",", names=True)
    xyz = np.column_stack([np.atleast_1d(frames[k]) for k in ("gt_x", "gt_y", "gt_z")])
    if not np.isfinite(xyz).all():
        return None
    distance = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz, axis=0), axis=1))])
    step_frames = steps["frame"].astype(int)
    return distance[step_frames], accounted_bytes(steps).astype(float)


@dataclass(frozen=True)
class AlignedPath:
    """An estimate of every frame, SE(3)-aligned to ground truth as the ATE is: xy (N, 2) and each frame's position
    error [m]."""

    xy: np.ndarray
    errors: np.ndarray


def aligned_paths(cell: FinishedCell) -> tuple[np.ndarray, dict[str, AlignedPath], np.ndarray] | None:
    """Ground-truth xy, the full-rate odometry and optimised trajectories aligned to it (trajectories/*.kitti, as
    the full-rate ATE aligns them) and the keyframes' frame indices (frames.csv); None when a file is missing or
    the alignment is undetermined (a straight prefix)."""
    from msa_slam.evaluation.trajectory import align_se3
    from msa_slam.io.poses import read_poses

    folder = cell.folder / "trajectories"
    try:
        gt = read_poses(folder / "gt.kitti", "kitti")[0]
        paths = {}
        for name in ("odometry", "optimised"):
            aligned = align_se3(read_poses(folder / f"{name}.kitti", "kitti")[0], gt)
            errors = np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=1)
            paths[name] = AlignedPath(aligned[:, :2, 3], errors)
        frames = np.genfromtxt(cell.folder / "frames.csv", delimiter=",", names=True)
    except (OSError, InputError):  # AlignmentError among them
        return None
    return gt[:, :2, 3], paths, np.flatnonzero(np.atleast_1d(frames["is_keyframe"]).astype(bool))
