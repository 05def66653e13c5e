"""HeLiPR (Jung et al., IJRR 2024) as kiss-icp's HeLiPR loader reads it: `LiDAR/<sensor>/<ns>.bin` scans of
packed records and `LiDAR_GT/global_<sensor>_gt.txt` (TUM rows: time x y z qx qy qz qw), for the sensors
Ouster, Velodyne, Aeva and Avia. Records are decoded with numpy instead of one struct call a point."""

from __future__ import annotations

import os
from functools import partial
from pathlib import Path

import numpy as np

from msa_slam.datasets.kiss_loaders import nanoseconds_to_seconds
from msa_slam.datasets.points import checked_points, field_names
from msa_slam.datasets.sequences import ScanSequence
from msa_slam.errors import InputError
from msa_slam.io.poses import read_poses

# kiss-icp's struct formats ("=" packing) as numpy records, with the time field and its unit in seconds
_RECORDS = {
    "Ouster": (
        np.dtype(
            [
                ("x", "<f4"),
                ("y", "<f4"),
                ("z", "<f4"),
                ("intensity", "<f4"),
                ("t", "<u4"),
                ("reflectivity", "<u2"),
                ("ring", "<u2"),
                ("ambient", "<u2"),
            ]
        ),
        "t",
        1e-9,
    ),
    "Velodyne": (
        np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2"), ("time", "<f4")]),
        "time",
        1.0,
    ),
    "Aeva": (
        np.dtype(
            [
                ("x", "<f4"),
                ("y", "<f4"),
                ("z", "<f4"),
                ("reflectivity", "<f4"),
                ("velocity", "<f4"),
                ("time_offset_ns", "<i4"),
                ("line_index", "<u1"),
                ("intensity", "<f4"),
            ]
        ),
        "time_offset_ns",
        1e-9,
    ),
    "Avia": (
        np.dtype(
            [
                ("x", "<f4"),
                ("y", "<f4"),
                ("z", "<f4"),
                ("reflectivity", "<u1"),
                ("tag", "<u1"),
                ("line", "<u1"),
                ("offset_time", "<u4"),
            ]
        ),
        "offset_time",
        1e-9,
    ),
}
HELIPR_SENSORS = tuple(_RECORDS)
AEVA_WITHOUT_INTENSITY = 1691936557946849179  # Aeva scans up to this time lack the intensity field (kiss-icp)


def _record(sensor: str, scan: Path) -> np.dtype:
    dtype = _RECORDS[sensor][0]
    if sensor == "Aeva" and scan.stem.isdigit() and int(scan.stem) <= AEVA_WITHOUT_INTENSITY:
        return np.dtype([(n, dtype[n]) for n in field_names(dtype)[:-1]])
    return dtype


def read_helipr_scan(scan: Path, sensor: str) -> tuple[np.ndarray, np.ndarray]:
    """Points (P, 3) and per-point seconds since the earliest point of one HeLiPR scan file."""
    dtype = _record(sensor, scan)
    size = scan.stat().st_size
    if size == 0 or size % dtype.itemsize:
        raise InputError(f"{scan}: {size} bytes is not a whole number of {dtype.itemsize}-byte {sensor} records")
    table = np.fromfile(scan, dtype=dtype)
    xyz = np.stack([table[a].astype(np.float64) for a in "xyz"], axis=1)
    keep = ~np.isnan(xyz).any(axis=1)
    _, field, unit = _RECORDS[sensor]
    times = table[field][keep].astype(np.float64) * unit
    return checked_points(xyz, scan), times - times.min()


def helipr_sequence(path: str | os.PathLike, sensor: str | None) -> ScanSequence:
    """One sensor (`sensor`: --sequence) of a HeLiPR sequence folder; ground truth when its file exists."""
    path = Path(path)
    if sensor not in _RECORDS:
        found = sorted(p.name for p in (path / "LiDAR").iterdir() if p.is_dir()) if (path / "LiDAR").is_dir() else []
        raise InputError(
            f"{path}: HeLiPR needs --sequence naming its LiDAR: one of {', '.join(HELIPR_SENSORS)} "
            f"(found under {path / 'LiDAR'}: {', '.join(found) or 'nothing'})"
        )
    folder = path / "LiDAR" / sensor
    scans = sorted(folder.glob("*.bin"), key=lambda p: int(p.stem) if p.stem.isdigit() else -1)
    if not scans:
        raise InputError(f"{folder}: no HeLiPR .bin scans (expected LiDAR/{sensor}/<nanoseconds>.bin)")
    bad = next((s for s in scans if not s.stem.isdigit()), None)
    if bad is not None:
        raise InputError(f"{bad}: HeLiPR scans are named by their time in nanoseconds")
    times = nanoseconds_to_seconds([int(s.stem) for s in scans])
    gt_file = path / "LiDAR_GT" / f"global_{sensor}_gt.txt"
    gt = None
    if gt_file.is_file():
        gt, _ = read_poses(gt_file, "tum")
        if len(gt) != len(scans):
            raise InputError(f"{gt_file}: {len(gt)} poses but {folder} has {len(scans)} scans")
    sequence = ScanSequence(
        path, scans, gt, times, timed_reader=partial(read_helipr_scan, sensor=sensor), kitti_bins=False
    )
    sequence.name = f"{path.name}-{sensor}"
    return sequence
