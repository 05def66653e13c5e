"""Small scan folders for the tests of what a command says before or around its work: random scans, and a straight
drive with its odometry file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from msa_slam.io.poses import write_poses


def write_scans(folder: Path, count: int) -> Path:
    """`count` KITTI .bin scans (x y z reflectance, float32) of random points 2-40 m around the sensor."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for k in range(count):
        points = rng.uniform(-40, 40, (2000, 4)).astype(np.float32)
        points[:, 2] = rng.uniform(-2, 5, 2000)
        points[:, :2] += np.sign(points[:, :2]) * 2
        points.tofile(folder / f"{k:06d}.bin")
    return folder


def write_straight_stream(folder: Path, frames: int) -> tuple[Path, Path]:
    """`frames` scans (folder/scans) and an odometry pose file (folder/odometry.txt) of a straight drive, 1.5 m a
    frame."""
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, 0, 3] = np.arange(frames) * 1.5
    write_poses(folder / "odometry.txt", poses)
    return write_scans(folder / "scans", frames), folder / "odometry.txt"
