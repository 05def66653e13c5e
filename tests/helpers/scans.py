"""Scans in the KITTI .bin layout: writing test files, and reading the shared KITTI 00 excerpt."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from conftest import shared_path


def write_bin(path: Path, points: np.ndarray) -> None:
    """points (n, 3) as a KITTI .bin file (float32 x, y, z, intensity 1), its folders made as needed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    np.hstack([points, np.ones((len(points), 1), np.float32)]).astype(np.float32).tofile(path)


def load_scan(name: str) -> np.ndarray:
    """Scan `name` (e.g. "000005") of ../shared/data/kitti_scans_00 as (n, 4) float32; skips when absent."""
    return np.fromfile(shared_path("data", "kitti_scans_00", f"{name}.bin"), dtype=np.float32).reshape(-1, 4)


def scan_points(index: int) -> np.ndarray:
    """The (n, 3) float32 points of scan `index` of the shared KITTI 00 excerpt."""
    return load_scan(f"{index:06d}")[:, :3]
