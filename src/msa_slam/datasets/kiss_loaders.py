"""The paper's other datasets with kiss_icp's conventions (ground-truth frames, file order, point times).

MulRan (Kim et al., ICRA 2020): `Ouster/*.bin` scans named by nanosecond time, `global_pose.csv` (time and
a 3x4 pose a row, more rows than scans). Its poses are the vehicle base's (x forward, z up) in a global
(UTM) frame, not the LiDAR's: the nearest in time to each scan is taken, made relative to the first and
moved to the Ouster frame with kiss_icp's base-to-Ouster calibration (MulRan's calib_base2ouster.txt: a
179.67 deg yaw, the Ouster faces backwards, 1.70 m ahead of the base and 1.80 m above it). Poses already in
the Ouster frame would come out turned by that yaw (a rotation ATE near 180 deg);
evaluation.sanity.reversed_ground_truth warns about them. As it ships the scans are under
`sensor_data/Ouster/`; kiss-icp's layout has `Ouster/` beside the pose file: both are read. Apollo-SouthBay
(Lu et al., CVPR 2019) and Newer College (Ramezani et al., IROS 2020) reuse kiss_icp's pose readers and file
order and take scan times from the pose file (Apollo) or the file names (Newer College); .pcd scans are read
with our own reader, so open3d and pyntcloud are not needed. MulRan and Newer College scans of 64 x 1024
points carry kiss_icp's column-major per-point times.
"""

from __future__ import annotations

import os
import re
from functools import partial
from pathlib import Path

import numpy as np

from msa_slam.datasets.clouds import read_bin
from msa_slam.datasets.ground_truth import nearest_in_time
from msa_slam.datasets.pcd import read_pcd
from msa_slam.datasets.sequences import ScanSequence
from msa_slam.errors import InputError
from msa_slam.io.poses import check_times, read_number_rows

KISS_DATASETS = ("mulran", "apollo", "ncd")
OUSTER_ROWS, OUSTER_COLUMNS = 64, 1024
SWEEP_PERIOD = 0.1  # s: MulRan's and Newer College's Ousters turn at 10 Hz
MULRAN_SCANS = ("sensor_data/Ouster", "Ouster")  # as shipped, kiss-icp's layout
APOLLO_COLUMNS = "index time x y z qx qy qz qw"
_NCD_NAME = re.compile(r"^cloud_(\d+)_(\d+)")


def _require(path: Path, what: str) -> Path:
    if not path.exists():
        raise InputError(f"{path}: missing ({what})")
    return path


def ouster_times(n_points: int) -> np.ndarray | None:
    """kiss_icp's per-point times (s) of a 64 x 1024 Ouster scan stored column by column; None for another size."""
    if n_points != OUSTER_ROWS * OUSTER_COLUMNS:
        return None
    return np.floor(np.arange(n_points) / OUSTER_ROWS) / OUSTER_COLUMNS * SWEEP_PERIOD


def nanoseconds_to_seconds(stamps: list[int]) -> np.ndarray:
    """Integer nanosecond times as float64 seconds, split first so differences keep their precision."""
    return np.array([s // 10**9 + (s % 10**9) * 1e-9 for s in stamps], dtype=np.float64)


def _with_ouster_times(reader, scan: Path) -> tuple[np.ndarray, np.ndarray | None]:
    points = reader(scan)
    return points, ouster_times(len(points))


def mulran_folder(path: Path) -> Path | None:
    """The Ouster scan folder of a MulRan sequence folder, in either layout (None when neither exists)."""
    return next((path / sub for sub in MULRAN_SCANS if (path / sub).is_dir()), None)


def mulran_poses(pose_file: Path, scan_times: np.ndarray) -> np.ndarray:
    """kiss_icp's MulRan ground truth: per scan (`scan_times` in s) the nearest pose in time, relative to the
    first, moved from the vehicle base's frame, the one global_pose.csv holds, to the Ouster's; a pose file that
    does not cover the scans is refused (see nearest_in_time)."""
    from kiss_icp.datasets.mulran import MulranDataset

    try:
        rows = np.loadtxt(pose_file, delimiter=",", ndmin=2)
    except ValueError as exc:
        raise InputError(
            f"{pose_file}: not MulRan's global_pose.csv (time, then 12 pose values a row): {exc}"
        ) from None
    if rows.shape[1] != 13:
        raise InputError(f"{pose_file}: {rows.shape[1]} values a row; MulRan's global_pose.csv has 13 (time, 3x4 pose)")
    pose_times = check_times(rows[:, 0] * 1e-9, lambda i: f"{pose_file}: row {i + 1}")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :4] = rows[:, 1:].reshape(-1, 3, 4)
    poses = poses[nearest_in_time(pose_times, scan_times, pose_file)]
    poses = np.linalg.inv(poses[0]) @ poses
    lidar_to_base, base_to_lidar = MulranDataset._get_calibration(None)
    return lidar_to_base @ poses @ base_to_lidar


def mulran_sequence(path: Path) -> ScanSequence:
    folder = mulran_folder(path)
    if folder is None:
        raise InputError(f"{path}: not a MulRan sequence (no {' or '.join(MULRAN_SCANS)} folder)")
    scans = sorted(folder.glob("*.bin"))
    bad = next((s for s in scans if not s.stem.isdigit()), None)
    if bad is not None:
        raise InputError(f"{bad}: MulRan scans are named by their time in nanoseconds")
    times = nanoseconds_to_seconds([int(s.stem) for s in scans])
    pose_file = path / "global_pose.csv"
    gt = mulran_poses(pose_file, times) if pose_file.is_file() and scans else None
    return ScanSequence(path, scans, gt, times, timed_reader=partial(_with_ouster_times, read_bin))


def apollo_times(pose_file: Path) -> np.ndarray:
    """The scan times of an Apollo-SouthBay gt_poses.txt (index, time, x y z, qx qy qz qw a line), after checking
    every line, so that kiss_icp's reader, which gives a bare ValueError, only ever gets a well-formed file."""
    rows, width = read_number_rows(pose_file), len(APOLLO_COLUMNS.split())
    for lineno, values in rows:
        if len(values) != width:
            raise InputError(
                f"{pose_file}:{lineno}: {len(values)} values; Apollo's gt_poses.txt has {width} a line "
                f"({APOLLO_COLUMNS})"
            )
    return np.array([values[1] for _, values in rows])


def kiss_sequence(name: str, path: str | os.PathLike) -> ScanSequence:
    """Open a MulRan, Apollo-SouthBay or Newer College sequence folder (`name`: mulran, apollo, ncd)."""
    path = Path(path)
    if name == "mulran":
        return mulran_sequence(path)
    if name == "apollo":
        from kiss_icp.datasets.apollo import ApolloDataset

        scans = sorted(
            _require(path / "pcds", "Apollo pcds/ folder").glob("*.pcd"),
            key=lambda p: int(p.stem) if p.stem.isdigit() else p.stem,
        )
        pose_file = _require(path / "poses" / "gt_poses.txt", "Apollo ground truth")
        times = apollo_times(pose_file)
        return ScanSequence(path, scans, ApolloDataset.read_poses(str(pose_file)), times, read_pcd)
    if name == "ncd":
        from kiss_icp.datasets.ncd import NewerCollegeDataset

        folder = _require(path / "raw_format" / "ouster_scan", "Newer College scan folder")
        pose_file = _require(path / "ground_truth" / "registered_poses.csv", "Newer College ground truth")
        names = NewerCollegeDataset.get_pcd_filenames(str(folder))
        stamps = [m for n in names if (m := _NCD_NAME.match(n))]
        named_times = np.array([int(m[1]) + 1e-9 * int(m[2]) for m in stamps]) if len(stamps) == len(names) else None
        return ScanSequence(
            path,
            [folder / f for f in names],
            NewerCollegeDataset.load_gt_poses(str(pose_file)),
            named_times,
            timed_reader=partial(_with_ouster_times, read_pcd),
        )
    raise InputError(f"unknown dataset loader {name!r}; choose one of {', '.join(KISS_DATASETS)}")
