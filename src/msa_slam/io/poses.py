"""Pose files: KITTI (12 numbers a line, row-major 3x4) and TUM (t x y z qx qy qz qw)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from msa_slam.errors import InputError
from msa_slam.io.atomic import write_text_atomic
from msa_slam.types import validate_poses

POSE_FORMATS = ("auto", "kitti", "tum")


def _read_rows(path: Path) -> list[tuple[int, list[float]]]:
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


def read_poses(path: str | os.PathLike, fmt: str = "auto") -> tuple[np.ndarray, np.ndarray | None]:
    """Read a pose file; return (poses (N,4,4), timestamps or None). `fmt`: auto, kitti or tum."""
    path = Path(path)
    if fmt not in POSE_FORMATS:
        raise InputError(f"unknown pose format {fmt!r}; choose one of {', '.join(POSE_FORMATS)}")
    rows = _read_rows(path)
    width = len(rows[0][1])
    if fmt == "auto":
        fmt = {12: "kitti", 8: "tum"}.get(width, "")
        if not fmt:
            raise InputError(
                f"{path}:{rows[0][0]}: {width} values a line; expected 12 (KITTI) or 8 (TUM)"
            )
    expected = 12 if fmt == "kitti" else 8
    for lineno, vals in rows:
        if len(vals) != expected:
            raise InputError(f"{path}:{lineno}: {len(vals)} values, expected {expected} ({fmt} format)")
    data = np.array([vals for _, vals in rows], dtype=np.float64)
    poses = np.tile(np.eye(4), (len(data), 1, 1))
    times = None
    if fmt == "kitti":
        poses[:, :3, :4] = data.reshape(-1, 3, 4)
    else:
        times = data[:, 0]
        poses[:, :3, 3] = data[:, 1:4]
        quat = data[:, 4:8]
        norms = np.linalg.norm(quat, axis=1)
        if not np.all(np.isfinite(quat)) or np.any(norms < 1e-9):
            k = int(np.argmax(~np.isfinite(quat).all(axis=1) | (norms < 1e-9)))
            raise InputError(f"{path}:{rows[k][0]}: invalid quaternion {quat[k].tolist()}")
        poses[:, :3, :3] = Rotation.from_quat(quat).as_matrix()
    return validate_poses(poses, where=str(path)), times


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


def write_poses(path: str | os.PathLike, poses: np.ndarray, fmt: str = "kitti",
                times: np.ndarray | None = None) -> None:
    """Write poses atomically in KITTI or TUM format."""
    poses = validate_poses(poses, where=str(path))
    if fmt == "kitti":
        write_text_atomic(path, format_kitti(poses))
    elif fmt == "tum":
        write_text_atomic(path, format_tum(poses, times))
    else:
        raise InputError(f"unknown pose format {fmt!r}; choose kitti or tum")
