"""Per-point times of spinning-LiDAR scans: derived from azimuth, or read from files stored beside the scans.

KITTI's .bin scans carry no time field. Its HDL-64 turns clockwise (seen from above) and a sweep starts and
ends facing backwards, so the forward-facing column, at the scan's timestamp, fires at mid-sweep. Like
kiss-icp's loaders, the time of a point is then its sweep fraction 0.5 * (1 - atan2(y, x) / pi) times the
sweep period. Sequences that store explicit times hold `velodyne_times/NNNNNN.npy` beside
`velodyne/NNNNNN.bin`: float32 seconds from the sweep start, one per point, in the scan's point order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from msa_slam.datasets.clouds import read_bin_records
from msa_slam.datasets.points import checked_points
from msa_slam.errors import InputError

SWEEP_PERIOD = 0.1  # s: KITTI's HDL-64 (and the simulator's sensors) turn at 10 Hz
TIMES_FOLDER = "velodyne_times"


def sweep_fraction(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Fraction of a clockwise sweep that starts facing backwards at which direction (x, y) is fired, in [0, 1)."""
    return np.mod(0.5 - np.arctan2(y, x) / (2 * np.pi), 1.0)


def azimuth_times(points: np.ndarray, period: float = SWEEP_PERIOD) -> np.ndarray:
    """(P,) float64 seconds from the sweep start of each point of a scan (P, >=2), from its azimuth."""
    return period * sweep_fraction(points[:, 0].astype(np.float64), points[:, 1].astype(np.float64))


def stored_times_path(scan: Path) -> Path:
    """Where the explicit per-point times of the KITTI-layout scan file `scan` are stored."""
    return scan.parent.parent / TIMES_FOLDER / f"{scan.stem}.npy"


def read_point_times(path: Path, raw_points: int, keep: np.ndarray | None = None) -> np.ndarray:
    """Stored per-point times (float64 s) of a scan with `raw_points` records, restricted to the points its
    reader kept (`keep`, a mask over the records); InputError naming `path` when they cannot be its times."""
    try:
        times = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(f"{path}: cannot read per-point times ({exc})") from None
    if times.ndim != 1 or len(times) != raw_points:
        raise InputError(
            f"{path}: {times.shape} per-point times for a scan of {raw_points} points; need one time a point"
        )
    times = times.astype(np.float64)
    if not np.isfinite(times).all():
        raise InputError(f"{path}: per-point times are not all finite numbers")
    return times if keep is None else times[keep]


def read_timed_scan(path: Path, stored: bool) -> tuple[np.ndarray, np.ndarray]:
    """A KITTI-layout .bin scan (P, 3) and its per-point times (P,): the `stored` ones (see module doc),
    else derived from azimuth."""
    raw = read_bin_records(path)
    points = checked_points(raw, path)
    if not stored:
        return points, azimuth_times(points)
    keep = None if len(points) == len(raw) else ~np.isnan(raw).any(axis=1)
    return points, read_point_times(stored_times_path(path), len(raw), keep)
