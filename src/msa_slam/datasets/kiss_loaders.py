"""The paper's other datasets through kiss_icp's loaders (scan lists and ground-truth conventions).

MulRan (Kim et al., ICRA 2020) uses kiss_icp's MulranDataset as is. Apollo-SouthBay (Lu et al., CVPR 2019)
and Newer College (Ramezani et al., IROS 2020) reuse kiss_icp's pose readers and file ordering but read the
.pcd scans with our own reader, so open3d and pyntcloud are not needed.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from msa_slam.datasets.clouds import read_bin, read_pcd
from msa_slam.datasets.sequences import ScanSequence
from msa_slam.errors import InputError

KISS_DATASETS = ("mulran", "apollo", "ncd")


def _require(path: Path, what: str) -> Path:
    if not path.exists():
        raise InputError(f"{path}: missing ({what})")
    return path


def kiss_sequence(name: str, path: str | os.PathLike) -> ScanSequence:
    """Open a MulRan, Apollo-SouthBay or Newer College sequence folder (`name`: mulran, apollo, ncd)."""
    path = Path(path)
    if name == "mulran":
        from kiss_icp.datasets.mulran import MulranDataset

        _require(path / "Ouster", "MulRan Ouster/ scan folder")
        _require(path / "global_pose.csv", "MulRan ground truth")
        data = MulranDataset(path)
        times = np.asarray(data.scan_timestamps, dtype=np.float64) * 1e-9
        return ScanSequence(path, [Path(f) for f in data.scan_files], np.asarray(data.gt_poses), times, read_bin)
    if name == "apollo":
        from kiss_icp.datasets.apollo import ApolloDataset

        scans = sorted(_require(path / "pcds", "Apollo pcds/ folder").glob("*.pcd"), key=lambda p: int(p.stem)
                       if p.stem.isdigit() else p.stem)
        poses = ApolloDataset.read_poses(str(_require(path / "poses" / "gt_poses.txt", "Apollo ground truth")))
        return ScanSequence(path, scans, poses, None, read_pcd)
    if name == "ncd":
        from kiss_icp.datasets.ncd import NewerCollegeDataset

        folder = _require(path / "raw_format" / "ouster_scan", "Newer College scan folder")
        pose_file = _require(path / "ground_truth" / "registered_poses.csv", "Newer College ground truth")
        scans = [folder / f for f in NewerCollegeDataset.get_pcd_filenames(str(folder))]
        return ScanSequence(path, scans, NewerCollegeDataset.load_gt_poses(str(pose_file)), None, read_pcd)
    raise InputError(f"unknown dataset loader {name!r}; choose one of {', '.join(KISS_DATASETS)}")
