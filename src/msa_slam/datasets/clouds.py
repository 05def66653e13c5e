"""Point-cloud file readers (.bin KITTI float32 x y z r, .ply through trimesh, .pcd: see pcd.py) with clear
errors."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from msa_slam.datasets.pcd import read_timed_pcd
from msa_slam.datasets.points import checked_points
from msa_slam.errors import InputError

CLOUD_SUFFIXES = (".bin", ".ply", ".pcd")


def check_bin_size(path: Path) -> None:
    """InputError unless the .bin file at `path` holds a whole, non-zero number of 16-byte points."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise InputError(f"{path}: cannot read scan file ({exc.strerror})") from None
    if size == 0:
        raise InputError(f"{path}: scan file is empty")
    if size % 16:
        raise InputError(f"{path}: {size} bytes is not a whole number of 16-byte (x, y, z, r) float32 points")


def read_bin_records(path: Path) -> np.ndarray:
    """Every (x, y, z) record of a KITTI .bin scan, NaN rows included (per-point times align with these)."""
    check_bin_size(path)
    return np.fromfile(path, dtype=np.float32).reshape(-1, 4)[:, :3]


def read_bin(path: str | os.PathLike) -> np.ndarray:
    """KITTI Velodyne scan: float32 records of x, y, z, reflectance (16 bytes each)."""
    path = Path(path)
    return checked_points(read_bin_records(path), path)


def read_ply(path: str | os.PathLike) -> np.ndarray:
    import trimesh

    path = Path(path)
    try:
        loaded = trimesh.load(path, force=None)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise InputError(f"{path}: cannot read PLY ({exc})") from exc
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    return checked_points(vertices.reshape(-1, 3), path)


def read_timed_cloud(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """(P, 3) points of one scan file, by suffix, and its per-point times when the file has them (.pcd)."""
    path = Path(path)
    readers = {".bin": read_bin, ".ply": read_ply}
    if path.suffix.lower() not in (*readers, ".pcd"):
        raise InputError(f"{path}: unsupported scan format; use one of {', '.join(CLOUD_SUFFIXES)}")
    if not path.is_file():
        raise InputError(f"{path}: scan file not found")
    if path.suffix.lower() == ".pcd":
        return read_timed_pcd(path)
    return readers[path.suffix.lower()](path), None


def read_cloud(path: str | os.PathLike) -> np.ndarray:
    """(P, 3) points of one scan file, by suffix."""
    return read_timed_cloud(path)[0]
