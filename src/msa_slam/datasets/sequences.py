"""Sequences of scan files: KITTI layout (Geiger et al., CVPR 2012), generic folders, kiss_icp's loaders."""

from __future__ import annotations

import copy
import logging
import os
from collections.abc import Callable, Iterator, Sequence
from functools import cache, partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from msa_slam.datasets.clouds import CLOUD_SUFFIXES, check_bin_size, read_cloud, read_timed_cloud
from msa_slam.datasets.frame import Frame
from msa_slam.datasets.point_times import TIMES_FOLDER, read_timed_scan, stored_times_path
from msa_slam.datasets.vertical_angle import CORRECTION_NAME, needs_correction, raise_elevation
from msa_slam.errors import InputError
from msa_slam.io.poses import check_times, read_poses
from msa_slam.types import pose_fault, validate_poses

if TYPE_CHECKING:
    from msa_slam.datasets.parsed import ParsedScans

log = logging.getLogger(__name__)

# Warned when a run reads scans without timestamps (and put in the run's report by the pipelines)
UNTIMED = "the scans have no timestamps (no times.txt or TUM ground truth); taking frame k to be at k s (1 frame/s)"


class ScanSequence:
    """Scans read lazily from files, with optional times and ground-truth poses (LiDAR frame).

    Opening checks what is cheap to check before any long work and reads no scan: that times increase
    strictly; `select` (which every run calls) checks the sizes of the .bin files it selects and reads the
    first of them, so a scan cut short or damaged outside `--first/--jump/-n` (scan 0 with `--first 1`) does
    not stop a run; every scan is checked again as it is read. A
    `timed_reader` (instead of `reader`) also gives each scan's per-point times, which frames then carry as
    `timestamps`; `point_time_files` (one a scan) are the files those times are read from, part of the
    sequence's identity for caches. `kitti_bins` False: .bin files are not KITTI's 16-byte records (HeLiPR).
    Without `times` the scans have no timestamps (`times_known` False): frame k is taken to be at k s.
    """

    # Defaults for subclasses that set their own fields (BagSequence: real times, no .bin files).
    times_known = True  # False: `times` are frame numbers, not timestamps
    kitti_bins = True
    forkable = True  # each scan read opens its own file: a reader forked from this process may read them
    correction: str | None = None  # what the reader corrects in every scan (see kitti_sequence); part of its identity
    _point_times: bool | None = None  # see point_times: None until a scan was read for it
    parsed: ParsedScans | None = None  # a run's copies of the text scans it parsed (datasets.parsed)

    def __init__(
        self,
        path: Path,
        scan_files: Sequence[Path],
        gt_poses: np.ndarray | None = None,
        times: np.ndarray | None = None,
        reader: Callable[[Path], np.ndarray] = read_cloud,
        timed_reader: Callable[[Path], tuple[np.ndarray, np.ndarray | None]] | None = None,
        kitti_bins: bool = True,
        point_time_files: Sequence[Path] = (),
    ) -> None:
        self.path = Path(path)
        self.name = self.path.name
        self.scan_files = [Path(f) for f in scan_files]
        if not self.scan_files:
            raise InputError(f"{self.path}: no scan files ({', '.join(CLOUD_SUFFIXES)}) found")
        for what, values in (("ground-truth poses", gt_poses), ("timestamps", times)):
            if values is not None and len(values) != len(self.scan_files):
                raise InputError(f"{self.path}: {len(values)} {what} but {len(self.scan_files)} scans")
        self.gt_poses = None if gt_poses is None else validate_poses(gt_poses, f"{self.path} poses")
        self.times_known = times is not None
        if times is None:
            times = np.arange(len(self.scan_files), dtype=np.float64)
        self.times = check_times(times, lambda i: f"{self.path}: timestamp of scan {self.scan_files[i].name}")
        self.point_time_files = [Path(f) for f in point_time_files]
        self._reader = reader
        self._timed_reader = timed_reader
        self.kitti_bins = kitti_bins

    def __len__(self) -> int:
        return len(self.scan_files)

    @property
    def point_times(self) -> bool:
        """Whether the frames carry per-point times (`Frame.timestamps`, which deskewing needs). That depends
        on the loader and the scan format, so the first frame tells: `select` reads it (the first scan a run
        reads, so a broken one fails before any long work); a sequence never selected reads it when asked."""
        if self._point_times is None:
            self._point_times = self[0].timestamps is not None
        return self._point_times

    def select(self, first: int = 0, jump: int = 1, count: int | None = None) -> ScanSequence:
        """Part of the recording: every `jump`-th scan from scan `first`, at most `count` of them (the frames
        keep their times and ground truth; indices restart at 0). What a run reads is known only here, so
        here the sizes of its .bin files are checked, its first scan read (point_times) and missing timestamps
        warned about."""
        selected_count(len(self), first, jump, count, str(self.path))
        part = self
        if (first, jump, count) != (0, 1, None):
            part = copy.copy(self)
            part._take(np.arange(first, len(self), jump)[:count])
        for scan in part.scan_files if part.kitti_bins else ():
            if scan.suffix.lower() == ".bin":
                check_bin_size(scan)
        part._point_times = part[0].timestamps is not None
        if not part.times_known:
            _warn_untimed(self.path)
        return part

    def _take(self, rows: np.ndarray) -> None:
        """Keep only the scans at `rows` (of this copy)."""
        self.scan_files = [self.scan_files[i] for i in rows]
        self.point_time_files = [self.point_time_files[i] for i in rows] if self.point_time_files else []
        self.gt_poses = None if self.gt_poses is None else self.gt_poses[rows]
        self.times = self.times[rows]

    def __getitem__(self, index: int) -> Frame:
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} scans")
        index %= len(self)
        gt = None if self.gt_poses is None else self.gt_poses[index]
        points, stamps = self._read(self.scan_files[index])
        return Frame(index, float(self.times[index]), points, gt, stamps)

    def _read(self, scan: Path) -> tuple[np.ndarray, np.ndarray | None]:
        if self.parsed is not None:
            return self.parsed.read(scan, self._read_file)
        return self._read_file(scan)

    def _read_file(self, scan: Path) -> tuple[np.ndarray, np.ndarray | None]:
        if self._timed_reader is not None:
            return self._timed_reader(scan)
        return self._reader(scan), None

    def __iter__(self) -> Iterator[Frame]:
        return (self[i] for i in range(len(self)))


def selected_count(total: int, first: int, jump: int, count: int | None, where: str) -> int:
    """How many of `total` scans every `jump`-th scan from `first`, at most `count`, selects; an InputError naming
    `where` for a selection that is malformed or starts beyond the last scan. Also checked before a simulated
    sequence is cast, from its frame count alone."""
    if first < 0 or jump < 1 or (count is not None and count < 1):
        raise InputError(
            f"{where}: bad selection first={first}, jump={jump}, n={count}; need first >= 0, jump >= 1, n >= 1"
        )
    if first >= total:
        raise InputError(f"{where}: --first {first} is beyond its {total} scans (0..{total - 1})")
    selected = len(range(first, total, jump))
    return selected if count is None else min(selected, count)


def read_times(path: Path) -> np.ndarray:
    """A KITTI times.txt: one time in seconds a line (blank and '#' lines skipped); errors name the line."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    values, lines = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            values.append(float(line))
        except ValueError:
            raise InputError(f"{path}:{lineno}: {line!r} is not a time in seconds (one number a line)") from None
        lines.append(lineno)
    if not values:
        raise InputError(f"{path}: no times")
    return check_times(values, lambda i: f"{path}:{lines[i]}")


def read_kitti_calibration(path: Path) -> np.ndarray:
    """The Velodyne->cam0 extrinsic `Tr` of a KITTI calib.txt as a 4x4 matrix.

    Tr must be rigid (rotation orthonormal with det 1 within ROTATION_TOLERANCE; KITTI's print 12 digits and
    are off by ~1e-7): the poses are converted as inv(Tr) P Tr, so a sheared or scaled Tr would otherwise be
    reported as the first converted pose not being rigid, naming the pose file instead of calib.txt."""
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        if line.startswith("Tr:"):
            values = line.split()[1:]
            if len(values) != 12:
                raise InputError(f"{path}:{lineno}: Tr needs 12 values, has {len(values)}")
            tr = np.eye(4)
            try:
                tr[:3, :4] = np.array(values, dtype=np.float64).reshape(3, 4)
            except ValueError as exc:
                raise InputError(f"{path}:{lineno}: Tr is not numeric ({exc})") from exc
            fault = pose_fault(tr[None])
            if fault is not None:
                raise InputError(
                    f"{path}:{lineno}: Tr (the Velodyne->camera extrinsic) {fault[1]}; it must be a "
                    "rotation and a translation"
                )
            return tr
    raise InputError(f"{path}: no 'Tr:' line (the Velodyne->camera extrinsic)")


def kitti_sequence(path: str | os.PathLike) -> ScanSequence:
    """A KITTI-layout sequence: velodyne/*.bin, calib.txt, optional times.txt and poses.

    Poses come from `poses.txt` in the sequence folder or from the benchmark's `../../poses/NN.txt`; they
    are cam0 poses, converted to the LiDAR frame as inv(Tr) P Tr (identity Tr for simulator output).
    Frames carry per-point times: those stored in velodyne_times/ (then one file per scan), else derived
    from azimuth (see `point_times`). A simulated sequence whose sim.json records a sensor elevation error
    (KITTI's HDL-64, realism preset "kitti") is read with kiss-icp's KITTI vertical-angle correction, as kiss-icp
    reads real KITTI (datasets.vertical_angle).
    """
    path = Path(path)
    velodyne = path / "velodyne"
    if not velodyne.is_dir():
        raise InputError(f"{path}: not a KITTI sequence (no velodyne/ folder)")
    # iterdir, unlike glob, raises PermissionError for an unreadable folder (glob would find "no scans")
    scans = sorted((f for f in velodyne.iterdir() if f.suffix == ".bin" and not _hidden(f)), key=_natural_key)
    if not scans:
        raise InputError(f"{velodyne}: no .bin scans")
    times = None
    if (path / "times.txt").is_file():
        times = read_times(path / "times.txt")
        if len(times) != len(scans):
            raise InputError(f"{path / 'times.txt'}: {len(times)} times but {velodyne} has {len(scans)} scans")
    gt = None
    candidates = [path / "poses.txt", path.parent.parent / "poses" / f"{path.name}.txt"]
    pose_file = next((p for p in candidates if p.is_file()), None)
    if pose_file is not None:
        calib = path / "calib.txt"
        if not calib.is_file():
            raise InputError(f"{calib}: missing; needed to convert {pose_file} from camera to LiDAR frame")
        tr = read_kitti_calibration(calib)
        cam, _ = read_poses(pose_file, "kitti")
        if len(cam) != len(scans):
            raise InputError(f"{pose_file}: {len(cam)} poses but {velodyne} has {len(scans)} scans")
        gt = np.linalg.inv(tr) @ cam @ tr
    stored = (path / TIMES_FOLDER).is_dir()
    if stored:
        missing = next((stored_times_path(s) for s in scans if not stored_times_path(s).is_file()), None)
        if missing is not None:
            raise InputError(
                f"{missing}: missing; {path / TIMES_FOLDER} must hold the per-point times of "
                "every scan (or be removed to derive them from azimuth)"
            )
    correct = needs_correction(path)
    reader = partial(_read_corrected, stored=stored) if correct else partial(read_timed_scan, stored=stored)
    sequence = ScanSequence(
        path,
        scans,
        gt,
        times,
        timed_reader=reader,
        point_time_files=[stored_times_path(s) for s in scans] if stored else (),
    )
    sequence.correction = CORRECTION_NAME if correct else None
    return sequence


def _read_corrected(path: Path, stored: bool) -> tuple[np.ndarray, np.ndarray]:
    """A KITTI-layout scan and its per-point times, its elevations corrected (the times, which depend on azimuth
    only, are read first and stay right)."""
    points, stamps = read_timed_scan(path, stored)
    return raise_elevation(points), stamps


def folder_sequence(
    path: str | os.PathLike, poses: str | os.PathLike | None = None, pose_format: str = "auto"
) -> ScanSequence:
    """A folder of .bin/.ply/.pcd scans (one format, natural order) with an optional LiDAR pose file."""
    path = Path(path)
    if not path.is_dir():
        raise InputError(f"{path}: scan folder not found")
    files = [f for f in path.iterdir() if f.suffix.lower() in CLOUD_SUFFIXES and f.is_file() and not _hidden(f)]
    suffixes = {f.suffix.lower() for f in files}
    if len(suffixes) > 1:
        raise InputError(f"{path}: mixes scan formats {sorted(suffixes)}; keep one format per folder")
    files.sort(key=_natural_key)
    gt, times = None, None
    if poses is not None:
        gt, times = read_poses(poses, pose_format)
        if len(gt) != len(files):
            raise InputError(f"{poses}: {len(gt)} poses but {path} has {len(files)} scans")
    return ScanSequence(path, files, gt, times, timed_reader=read_timed_cloud)


def load_cloud_stack(source: str | os.PathLike, n_frames: int) -> list[np.ndarray]:
    """Per-frame clouds from a folder of scans (.bin/.ply/.pcd) or one .npy array (N, P, 3); the count must
    match the `n_frames` poses they go with."""
    source = Path(source)
    if source.suffix == ".npy":
        try:
            clouds = np.load(source, allow_pickle=False)
        except (OSError, ValueError, EOFError) as exc:
            raise InputError(f"{source}: not a readable .npy array ({exc})") from exc
        if clouds.ndim != 3 or clouds.shape[2] not in (3, 4):  # (N, 20, 60) would be descriptors, not points
            raise InputError(
                f"{source}: clouds must have shape (N, P, 3) (x y z) or (N, P, 4) (x y z intensity), got {clouds.shape}"
            )
        items = list(clouds)
    else:
        items = [read_cloud(f) for f in folder_sequence(source).scan_files]
    if len(items) != n_frames:
        raise InputError(f"{source}: {len(items)} clouds, but the pose file has {n_frames} poses")
    return items


@cache
def _warn_untimed(path: Path) -> None:
    """Warn once a folder and process: a run opens its dataset once, but an experiment grid runs its cells
    on one dataset one after another in one process, each opening it."""
    log.warning("%s: %s", path, UNTIMED)


def _hidden(path: Path) -> bool:
    """Hidden files are not scans: macOS leaves ._000000.bin beside copied scans (resource forks)."""
    return path.name.startswith(".")


def _natural_key(path: Path) -> list:
    import re

    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]
