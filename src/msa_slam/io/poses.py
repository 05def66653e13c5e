"""Pose files: KITTI (12 numbers a line, row-major 3x4) and TUM (t x y z qx qy qz qw)."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from msa_slam.errors import InputError
from msa_slam.io.atomic import write_text_atomic
from msa_slam.types import ROTATION_TOLERANCE, pose_fault, validate_poses

POSE_FORMATS = ("auto", "kitti", "tum")
TUM_COLUMNS = "time tx ty tz qx qy qz qw"
# How far a TUM quaternion's norm may be from 1 and still be normalised rather than refused: writers that
# print 4-6 decimals leave deviations up to ~1e-4, while a swapped column or a corrupt line is far off (0.7).
QUATERNION_TOLERANCE = 1e-2


def read_number_rows(path: Path) -> list[tuple[int, list[float]]]:
    """(line number, values) of every line of a text file of numbers (blank and # lines skipped); one
    InputError naming the file and line for anything else."""
    if path.is_dir():
        raise InputError(f"{path}: is a directory; expected a pose file (KITTI or TUM)")
    if not path.is_file():
        raise InputError(f"{path}: pose file not found")
    rows = []
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read pose file ({exc})") from exc
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            rows.append((lineno, [float(v) for v in line.replace(",", " ").split()]))
        except ValueError as exc:
            raise InputError(f"{path}:{lineno}: not a number ({exc})") from exc
    if not rows:
        raise InputError(f"{path}: pose file is empty")
    return rows


def read_poses(
    path: str | os.PathLike, fmt: str = "auto", rotation_tolerance: float = ROTATION_TOLERANCE
) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a pose file; return (poses (N,4,4), timestamps or None). `fmt`: auto, kitti or tum.

    A TUM file's times must be finite and increase strictly and its quaternions be of unit norm (within
    QUATERNION_TOLERANCE): every reader of the file (ground truth, odometry, `sample`) then gets the same
    check, and its error names the line to fix. A KITTI rotation may be off orthonormal by `rotation_tolerance`.
    """
    path = Path(path)
    if fmt not in POSE_FORMATS:
        raise InputError(f"unknown pose format {fmt!r}; choose one of {', '.join(POSE_FORMATS)}")
    rows = read_number_rows(path)
    width = len(rows[0][1])
    if fmt == "auto":
        fmt = {12: "kitti", 8: "tum"}.get(width, "")
        if not fmt:
            raise InputError(f"{path}:{rows[0][0]}: {width} values a line; expected 12 (KITTI) or 8 (TUM)")
    expected = 12 if fmt == "kitti" else 8
    for lineno, vals in rows:
        if len(vals) != expected:
            raise InputError(f"{path}:{lineno}: {len(vals)} values, expected {expected} ({fmt} format)")
    data = np.array([vals for _, vals in rows], dtype=np.float64)
    lines = [lineno for lineno, _ in rows]
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    times = None
    if fmt == "kitti":
        poses[:, :3, :4] = data.reshape(-1, 3, 4)
    else:
        times = check_times(data[:, 0], lambda i: f"{path}: pose {i + 1}", lines)
        poses[:, :3, 3] = data[:, 1:4]
        poses[:, :3, :3] = Rotation.from_quat(_unit_quaternions(path, data[:, 4:8], lines)).as_matrix()
    fault = pose_fault(poses, rotation_tolerance)
    if fault is not None:  # the file's line (comments counted), as the parse errors above name it
        raise InputError(f"{path}:{lines[fault[0]]}: pose {fault[1]}")
    return poses, times


def check_times(times: ArrayLike, where: Callable[[int], str], lines: Sequence[int] | None = None) -> np.ndarray:
    """`times` as a float64 array if finite and strictly increasing, else an InputError naming `where(i)`
    (and, given the file `lines` the times were read from, the lines of the bad time and the one before).

    Frames are matched to evaluation tools by time, so a NaN, repeated or backward time would silently
    break the TUM outputs rather than fail here.
    """
    values = np.asarray(times, dtype=np.float64).ravel()

    def on_line(i: int) -> str:
        return "" if lines is None else f" on line {lines[i]}"

    bad = np.flatnonzero(~np.isfinite(values))
    if len(bad):
        i = int(bad[0])
        raise InputError(f"{where(i)}: time {values[i]} is not a finite number{on_line(i)}")
    steps = np.flatnonzero(np.diff(values) <= 0)
    if len(steps):
        i = int(steps[0]) + 1
        what = "repeats" if values[i] == values[i - 1] else "is before"
        raise InputError(
            f"{where(i)}: time {float(values[i])!r} {what} the previous one ({float(values[i - 1])!r}"
            f"{on_line(i - 1)}){on_line(i)}; times must increase strictly"
        )
    return values


def _unit_quaternions(path: Path, quats: np.ndarray, lines: Sequence[int]) -> np.ndarray:
    """`quats` (qx qy qz qw rows) if each has norm 1 within QUATERNION_TOLERANCE, else an InputError naming the
    line: normalising a far-off quaternion (a corrupt line, columns in another order) would hide the fault."""
    norms = np.linalg.norm(quats, axis=1)
    bad = np.flatnonzero(~(np.abs(norms - 1.0) <= QUATERNION_TOLERANCE))  # NaN norms compare False: refused
    if len(bad):
        k = int(bad[0])
        raise InputError(
            f"{path}:{lines[k]}: quaternion (qx qy qz qw) {quats[k].tolist()} has norm {norms[k]:.6g}, "
            f"not 1 (allowed deviation {QUATERNION_TOLERANCE:g}); TUM columns are {TUM_COLUMNS}"
        )
    return quats


def format_kitti(poses: np.ndarray) -> str:
    return "".join(" ".join(f"{v:.9e}" for v in p[:3, :4].ravel()) + "\n" for p in poses)


def format_tum(poses: np.ndarray, times: np.ndarray | None = None) -> str:
    if times is None:
        times = np.arange(len(poses), dtype=np.float64)
    quats = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
    lines = []
    for t, p, q in zip(times, poses, quats):
        vals = [t, *p[:3, 3], *q]
        lines.append(" ".join(f"{v:.9f}" for v in vals))
    return "\n".join(lines) + "\n"


def write_poses(
    path: str | os.PathLike, poses: np.ndarray, fmt: str = "kitti", times: np.ndarray | None = None
) -> None:
    """Write poses atomically in KITTI or TUM format."""
    poses = validate_poses(poses, where=str(path))
    if fmt == "kitti":
        write_text_atomic(path, format_kitti(poses))
    elif fmt == "tum":
        write_text_atomic(path, format_tum(poses, times))
    else:
        raise InputError(f"unknown pose format {fmt!r}; choose kitti or tum")
