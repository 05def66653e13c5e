"""Point-cloud file readers (.bin KITTI float32 x y z r, .ply through trimesh, .pcd) with clear errors."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from msa_slam.errors import InputError

CLOUD_SUFFIXES = (".bin", ".ply", ".pcd")
_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("I", 1): "<i1", ("I", 2): "<i2", ("I", 4): "<i4",
              ("I", 8): "<i8", ("U", 1): "<u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8"}


MAX_COORDINATE = 1e4  # metres: beyond any LiDAR's range, so a larger value means the file is misread
TINY = 1e-20  # metres: magnitudes no measurement has (the bit patterns of other types read as float32)


def checked_points(points: np.ndarray, path: Path) -> np.ndarray:
    """Finite points of a scan, or an InputError naming `path` when it is empty or cannot be a LiDAR scan.

    NaN rows are dropped (drivers mark missing returns so); infinite or larger-than-sensor coordinates, or
    most points at sub-1e-20 magnitudes, mean the bytes were read as the wrong type (e.g. float64 scans).
    """
    if len(points) == 0:
        raise InputError(f"{path}: scan has no points")
    points = points[~np.isnan(points).any(axis=1)]
    if len(points) == 0:
        raise InputError(f"{path}: scan has no finite points")
    magnitude = np.abs(points)
    hint = "; KITTI .bin scans are float32 x, y, z, reflectance" if path.suffix.lower() == ".bin" else ""
    largest = float(magnitude.max())
    if not largest <= MAX_COORDINATE:
        raise InputError(f"{path}: coordinate {largest:.3g} m is beyond any sensor's range (|x| <= "
                         f"{MAX_COORDINATE:g} m){hint}")
    tiny = float(((magnitude > 0) & (magnitude < TINY)).any(axis=1).mean())
    if tiny > 0.5:
        raise InputError(f"{path}: {100 * tiny:.0f} % of the points have coordinates below {TINY:g} m in "
                         f"magnitude, which no LiDAR measures{hint}")
    return points


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


def read_pcd(path: str | os.PathLike) -> np.ndarray:
    """PCD v0.7 (ascii or binary; not binary_compressed): the x, y, z fields."""
    path = Path(path)
    raw = path.read_bytes()
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = raw.find(b"\n", offset)
        if end < 0:
            raise InputError(f"{path}: PCD header has no DATA line")
        line = raw[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        name, *values = line.split()
        header[name.upper()] = values
        if name.upper() == "DATA":
            break
    try:
        fields = header["FIELDS"]
        sizes = [int(v) for v in header["SIZE"]]
        types = header["TYPE"]
        counts = [int(v) for v in header.get("COUNT", ["1"] * len(fields))]
        num_points = int(header["POINTS"][0])
        mode = header["DATA"][0].lower()
    except (KeyError, ValueError, IndexError) as exc:
        raise InputError(f"{path}: malformed PCD header ({exc})") from exc
    if not {"x", "y", "z"} <= set(fields):
        raise InputError(f"{path}: PCD has fields {fields}, needs x, y and z")
    if mode == "ascii":
        columns = np.cumsum([0] + counts)
        table = np.loadtxt(raw[offset:].decode("ascii").splitlines(), ndmin=2)
        if table.shape[0] != num_points or table.shape[1] != columns[-1]:
            raise InputError(f"{path}: PCD declares {num_points} points but its data has shape {table.shape}")
        xyz = np.stack([table[:, columns[fields.index(a)]] for a in "xyz"], axis=1)
    elif mode == "binary":
        try:
            dtype = np.dtype([(f, _PCD_TYPES[(t.upper(), s)], (c,) if c > 1 else ())
                              for f, s, t, c in zip(fields, sizes, types, counts)])
        except KeyError as exc:
            raise InputError(f"{path}: unsupported PCD field type {exc}") from exc
        if len(raw) - offset < num_points * dtype.itemsize:
            raise InputError(f"{path}: PCD data is truncated ({len(raw) - offset} bytes for {num_points} points)")
        table = np.frombuffer(raw, dtype=dtype, count=num_points, offset=offset)
        xyz = np.stack([table[a].astype(np.float64) for a in "xyz"], axis=1)
    else:
        raise InputError(f"{path}: PCD DATA {mode!r} is not supported (use ascii or binary)")
    return checked_points(xyz, path)


def read_cloud(path: str | os.PathLike) -> np.ndarray:
    """(P, 3) points of one scan file, by suffix."""
    path = Path(path)
    readers = {".bin": read_bin, ".ply": read_ply, ".pcd": read_pcd}
    reader = readers.get(path.suffix.lower())
    if reader is None:
        raise InputError(f"{path}: unsupported scan format; use one of {', '.join(CLOUD_SUFFIXES)}")
    if not path.is_file():
        raise InputError(f"{path}: scan file not found")
    return reader(path)
