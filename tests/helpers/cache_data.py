"""The cache tests' data: a 12-scan KITTI-layout excerpt of the simulated "test" sequence (conftest.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from msa_slam.io.poses import read_poses, write_poses
from msa_slam.sim.sequence import CALIB_TEXT

N_SCANS = 12


def fill_excerpt(data: Path, source: Path, first: int) -> Path:
    """Write scans first..first+11 of `source` (and their poses) into the KITTI-layout folder `data`, in place."""
    (data / "velodyne").mkdir(parents=True, exist_ok=True)
    gt, _ = read_poses(source / "poses.txt")
    for i in range(N_SCANS):
        (data / "velodyne" / f"{i:06d}.bin").write_bytes((source / "velodyne" / f"{first + i:06d}.bin").read_bytes())
    write_poses(data / "poses.txt", gt[first : first + N_SCANS])
    (data / "calib.txt").write_text(CALIB_TEXT)
    return data


@pytest.fixture
def data(sequence, tmp_path) -> Path:
    """The excerpt from scan 0, in tmp_path/data."""
    return fill_excerpt(tmp_path / "data", sequence, 0)
