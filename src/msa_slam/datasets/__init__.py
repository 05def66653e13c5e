"""Scan sources: KITTI-layout sequences, generic scan folders, MulRan, HeLiPR, Apollo, Newer College, ROS bags.

`open_dataset` picks the loader from the folder's layout (LOADERS lists each one's layout, which --help and
the errors show) unless one is named.
"""

from __future__ import annotations

import os
from pathlib import Path

from msa_slam.datasets.bags import BagSequence, is_bag
from msa_slam.datasets.clouds import CLOUD_SUFFIXES, read_bin, read_cloud, read_ply
from msa_slam.datasets.frame import Frame
from msa_slam.datasets.ground_truth import attach_ground_truth
from msa_slam.datasets.helipr import HELIPR_SENSORS, helipr_sequence
from msa_slam.datasets.kiss_loaders import KISS_DATASETS, kiss_sequence, mulran_folder
from msa_slam.datasets.options import SourceOptions
from msa_slam.datasets.parsed import ParsedScans
from msa_slam.datasets.pcd import read_pcd
from msa_slam.datasets.sequences import ScanSequence, folder_sequence, kitti_sequence, read_kitti_calibration
from msa_slam.errors import InputError

LOADERS = {
    "kitti": "velodyne/*.bin + calib.txt, poses.txt or ../../poses/NN.txt (a KITTI odometry root: --sequence NN)",
    "mulran": "sensor_data/Ouster/*.bin (as shipped) or Ouster/*.bin, + global_pose.csv",
    "helipr": f"LiDAR/<sensor>/*.bin + LiDAR_GT/global_<sensor>_gt.txt; --sequence <sensor> "
    f"({', '.join(HELIPR_SENSORS)})",
    "apollo": "pcds/*.pcd + poses/gt_poses.txt",
    "ncd": "raw_format/ouster_scan/cloud_<s>_<ns>.pcd + ground_truth/registered_poses.csv (Newer College)",
    "rosbag": "ROS1 .bag (or a folder of split .bag files), ROS2 bag folder, .db3 or .mcap file; --topic picks "
    "the PointCloud2 topic",
    "folder": "a folder of .bin / .pcd / .ply scans (one format, natural order); ground truth with --gt",
}


def detect_loader(path: Path) -> str:
    """The loader whose layout `path` has (folder when none does)."""
    if is_bag(path):
        return "rosbag"
    if path.is_dir():
        if (path / "velodyne").is_dir():
            return "kitti"
        if (path / "LiDAR").is_dir():
            return "helipr"
        if mulran_folder(path) is not None:
            return "mulran"
        if (path / "pcds").is_dir():
            return "apollo"
        if (path / "raw_format" / "ouster_scan").is_dir():
            return "ncd"
    return "folder"


def sequence_folder(path: Path, sequence: str) -> Path:
    """The sequence `sequence` of a dataset root: ROOT/sequences/NAME (KITTI) or ROOT/NAME (MulRan, ...)."""
    for candidate in (path / "sequences" / sequence, path / sequence):
        if candidate.is_dir():
            return candidate
    root = path / "sequences" if (path / "sequences").is_dir() else path
    found = sorted(p.name for p in root.iterdir() if p.is_dir()) if root.is_dir() else []
    raise InputError(
        f"{path}: no sequence {sequence!r} (looked for {path / 'sequences' / sequence} and "
        f"{path / sequence}); sequences there: {', '.join(found[:20]) or 'none'}"
    )


def check_scan_folder(path: Path, sequence_option: bool = True) -> None:
    """Name the likely mix-up when `path`, to be read as a folder of scans, holds none: a single scan file, a
    KITTI sequence (scans in velodyne/) or, where --sequence could pick one (`sequence_option`), a KITTI
    dataset root (sequences/NN/velodyne). Otherwise the folder loader's errors follow."""
    if path.is_file():
        if path.suffix.lower() in CLOUD_SUFFIXES:
            raise InputError(
                f"{path}: is a single scan file, not a folder of scans; pass the folder that holds "
                f"the scans ({path.parent})"
            )
        raise InputError(f"{path}: is a file, neither a folder of scans nor a ROS bag ({LOADERS['rosbag']})")
    if not path.is_dir() or any(
        f.suffix.lower() in CLOUD_SUFFIXES and not f.name.startswith(".") for f in path.iterdir()
    ):
        return
    missing = f"{path}: no scan files ({', '.join(CLOUD_SUFFIXES)}) found"
    if (path / "velodyne").is_dir():
        raise InputError(f"{missing}; it looks like a KITTI sequence: its scans are in {path / 'velodyne'}")
    sequences = sorted(p.parent.name for p in (path / "sequences").glob("*/velodyne") if p.is_dir())
    if sequences and sequence_option:
        raise InputError(
            f"{missing}; it looks like a KITTI dataset root: pass --sequence {sequences[0]} "
            f"(sequences there: {', '.join(sequences)})"
        )


def open_dataset(
    path: str | os.PathLike,
    kind: str = "auto",
    poses: str | os.PathLike | None = None,
    pose_format: str = "auto",
    topic: str | None = None,
    sequence: str | None = None,
) -> ScanSequence:
    """Open a sequence with loader `kind` (auto: from the layout; see LOADERS). `poses` (a LiDAR-frame KITTI
    or TUM pose file) is its ground truth; `topic` picks a bag's PointCloud2 topic; `sequence` a sequence
    of a dataset root (HeLiPR: the sensor)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: dataset not found")
    if kind != "auto" and kind not in LOADERS:
        raise InputError(f"unknown dataset loader {kind!r}; choose one of {', '.join(['auto', *LOADERS])}")
    if sequence is not None and kind != "helipr" and not (kind == "auto" and (path / "LiDAR").is_dir()):
        path = sequence_folder(path, sequence)
    if kind == "auto":
        kind = detect_loader(path)
    if topic is not None and kind != "rosbag":
        raise InputError(
            f"--topic {topic}: {path} is read by the {kind} loader, not as a ROS bag ({LOADERS['rosbag']})"
        )
    if kind == "folder":
        check_scan_folder(path)
        return folder_sequence(path, poses, pose_format)
    if kind == "kitti":
        opened = kitti_sequence(path)
    elif kind == "rosbag":
        opened = BagSequence(path, topic)
    elif kind == "helipr":
        opened = helipr_sequence(path, sequence)
    else:
        opened = kiss_sequence(kind, path)
    return opened if poses is None else attach_ground_truth(opened, poses, pose_format)


def open_source_options(
    path: str | os.PathLike, kind: str, options: SourceOptions, parsed: ParsedScans | None = None
) -> ScanSequence:
    """open_dataset with a run's source options, then the part of the recording they select; `parsed` keeps the
    text scans the run parses (select reads the first)."""
    sequence = open_dataset(path, kind, options.gt, options.gt_format, options.topic, options.sequence)
    sequence.parsed = parsed
    return sequence.select(options.first, options.jump, options.frames)


__all__ = [
    "BagSequence",
    "Frame",
    "KISS_DATASETS",
    "LOADERS",
    "ParsedScans",
    "ScanSequence",
    "SourceOptions",
    "check_scan_folder",
    "detect_loader",
    "folder_sequence",
    "kiss_sequence",
    "kitti_sequence",
    "open_dataset",
    "open_source_options",
    "read_bin",
    "read_cloud",
    "read_kitti_calibration",
    "read_pcd",
    "read_ply",
]
