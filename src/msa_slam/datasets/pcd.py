"""PCD files (PCL's format, v0.7): DATA ascii, binary and binary_compressed (LZF, fields stored one after
another), the x, y, z fields and, when present, the per-point time field drivers write (t, time, timestamp)."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from msa_slam.datasets.points import checked_points, field_names
from msa_slam.errors import InputError

PCD_TYPES = {
    ("F", 4): "<f4",
    ("F", 8): "<f8",
    ("I", 1): "<i1",
    ("I", 2): "<i2",
    ("I", 4): "<i4",
    ("I", 8): "<i8",
    ("U", 1): "<u1",
    ("U", 2): "<u2",
    ("U", 4): "<u4",
    ("U", 8): "<u8",
}
PCD_MODES = ("ascii", "binary", "binary_compressed")
TIME_FIELDS = ("t", "time", "timestamp", "timestamps")  # kiss-icp's names; integer ones count nanoseconds


def _header(raw: bytes, path: Path) -> tuple[dict[str, list[str]], int]:
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
            return header, offset


def _dtype(fields: list[str], sizes: list[int], types: list[str], counts: list[int], path: Path) -> np.dtype:
    try:
        return np.dtype(
            [(f, PCD_TYPES[(t.upper(), s)], (c,) if c > 1 else ()) for f, s, t, c in zip(fields, sizes, types, counts)]
        )
    except KeyError as exc:
        raise InputError(f"{path}: unsupported PCD field type {exc}") from None


def _compressed(raw: bytes, offset: int, dtype: np.dtype, n: int, path: Path) -> np.ndarray:
    """binary_compressed: two uint32 sizes, then LZF data that decodes to each field's n values in turn."""
    from msa_slam.datasets.lzf import lzf_decompress  # numba: loaded only for compressed files

    if len(raw) - offset < 8:
        raise InputError(f"{path}: PCD binary_compressed data is truncated (no size words)")
    packed, size = struct.unpack_from("<II", raw, offset)
    if size != n * dtype.itemsize:
        raise InputError(
            f"{path}: PCD binary_compressed declares {size} bytes for {n} points of {dtype.itemsize} bytes"
        )
    data = raw[offset + 8 : offset + 8 + packed]
    if len(data) < packed:
        raise InputError(f"{path}: PCD binary_compressed data is truncated ({len(data)} of {packed} bytes)")
    plain = lzf_decompress(data, size, f"{path}") if n else b""
    table = np.empty(n, dtype=dtype)
    start = 0
    for name in field_names(dtype):
        field = dtype[name]
        table[name] = np.frombuffer(
            plain, dtype=field.base, count=n * max(1, int(np.prod(field.shape))), offset=start
        ).reshape((n, *field.shape))
        start += n * field.itemsize
    return table


def _ascii_fault(path: Path, lines: list[str], header_lines: int, width: int, exc: ValueError) -> str:
    """What np.loadtxt refused in the DATA ascii `lines`, naming the file line (loadtxt's row numbers skip
    blank lines and count from the data)."""
    for k, line in enumerate(lines, start=header_lines + 1):
        values = line.split("#")[0].split()
        if not values:
            continue
        bad = next((v for v in values if not _is_number(v)), None)
        if bad is not None:
            return f"{path}:{k}: {bad!r} is not a number (PCD DATA ascii: {width} numbers a point)"
        if len(values) != width:
            return f"{path}:{k}: {len(values)} values; its fields need {width} a point"
    return f"{path}: unreadable PCD ascii data ({exc})"


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_pcd_table(path: str | os.PathLike) -> np.ndarray:
    """Every field of every point of a PCD file as a structured array (one row a point)."""
    path = Path(path)
    raw = path.read_bytes()
    header, offset = _header(raw, path)
    try:
        fields = header["FIELDS"]
        sizes = [int(v) for v in header["SIZE"]]
        types = header["TYPE"]
        counts = [int(v) for v in header.get("COUNT", ["1"] * len(fields))]
        n = int(header["POINTS"][0])
        mode = header["DATA"][0].lower()
    except (KeyError, ValueError, IndexError) as exc:
        raise InputError(f"{path}: malformed PCD header ({exc})") from None
    if not {"x", "y", "z"} <= set(fields):
        raise InputError(f"{path}: PCD has fields {fields}, needs x, y and z")
    if mode not in PCD_MODES:
        raise InputError(f"{path}: PCD DATA {mode!r} is not a PCD encoding ({', '.join(PCD_MODES)})")
    fields = [f if f != "_" else f"_pad{k}" for k, f in enumerate(fields)]
    dtype = _dtype(fields, sizes, types, counts, path)
    if mode == "binary_compressed":
        return _compressed(raw, offset, dtype, n, path)
    if mode == "binary":
        if len(raw) - offset < n * dtype.itemsize:
            raise InputError(f"{path}: PCD data is truncated ({len(raw) - offset} bytes for {n} points)")
        return np.frombuffer(raw, dtype=dtype, count=n, offset=offset)
    lines = raw[offset:].decode("ascii", errors="replace").splitlines()
    try:
        flat = np.loadtxt(lines, ndmin=2)
    except ValueError as exc:
        raise InputError(_ascii_fault(path, lines, raw[:offset].count(b"\n"), sum(counts), exc)) from None
    if flat.shape != (n, sum(counts)):
        raise InputError(f"{path}: PCD declares {n} points but its data has shape {flat.shape}")
    table = np.empty(n, dtype=dtype)
    column = 0
    for name, count in zip(fields, counts):
        table[name] = flat[:, column] if count == 1 else flat[:, column : column + count]
        column += count
    return table


def _time_field(table: np.ndarray) -> str | None:
    return next((f for f in TIME_FIELDS if f in field_names(table.dtype)), None)


def read_timed_pcd(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (P, 3) of a PCD file and, when it has a time field, each point's seconds since the earliest."""
    path = Path(path)
    table = read_pcd_table(path)
    xyz = np.stack([table[a].astype(np.float64) for a in "xyz"], axis=1)
    keep = ~np.isnan(xyz).any(axis=1)
    points = checked_points(xyz, path)
    name = _time_field(table)
    if name is None:
        return points, None
    raw = table[name]
    scale = 1e-9 if raw.dtype.kind in "iu" else 1.0
    times = raw[keep].astype(np.float64)
    return points, (times - times.min()) * scale


def read_pcd(path: str | os.PathLike) -> np.ndarray:
    """PCD v0.7 (ascii, binary or binary_compressed): the x, y, z fields."""
    return read_timed_pcd(path)[0]
