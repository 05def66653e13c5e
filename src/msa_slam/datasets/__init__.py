"""Scan sources: KITTI-layout sequences, generic scan folders, MulRan/Apollo/Newer College via kiss_icp."""

from __future__ import annotations

import os
from pathlib import Path

from msa_slam.datasets.clouds import read_bin, read_cloud, read_pcd, read_ply
from msa_slam.datasets.frame import Frame
from msa_slam.datasets.kiss_loaders import KISS_DATASETS, kiss_sequence
from msa_slam.datasets.sequences import (ScanSequence, folder_sequence, kitti_sequence,
                                         read_kitti_calibration)
from msa_slam.errors import InputError


def open_dataset(path: str | os.PathLike, kind: str = "auto", poses: str | os.PathLike | None = None,
                 pose_format: str = "auto") -> ScanSequence:
    """Open a sequence; `kind`: auto (KITTI layout if velodyne/ exists, else a scan folder), kitti, folder,
    or one of KISS_DATASETS. `poses` (a LiDAR-frame pose file) applies to scan folders."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: dataset not found")
    if kind == "auto":
        kind = "kitti" if (path / "velodyne").is_dir() else "folder"
    if kind == "kitti":
        return kitti_sequence(path)
    if kind == "folder":
        return folder_sequence(path, poses, pose_format)
    return kiss_sequence(kind, path)


__all__ = ["Frame", "KISS_DATASETS", "ScanSequence", "folder_sequence", "kiss_sequence", "kitti_sequence",
           "open_dataset", "read_bin", "read_cloud", "read_kitti_calibration", "read_pcd", "read_ply"]
