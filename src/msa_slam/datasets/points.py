"""What the points of a LiDAR scan may be, whichever reader (scan file, bag message) decoded them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from msa_slam.errors import InputError

MAX_COORDINATE = 1e4  # metres: beyond any LiDAR's range, so a larger value means the file is misread
TINY = 1e-20  # metres: magnitudes no measurement has (the bit patterns of other types read as float32)


def checked_points(points: np.ndarray, path: Path) -> np.ndarray:
    """Finite points of a scan, or an InputError naming `path` when it is empty or cannot be a LiDAR scan.

    NaN rows are dropped (drivers mark missing returns so); infinite or larger-than-sensor coordinates, or
    most points at sub-1e-20 magnitudes, mean the bytes were read as the wrong type (e.g. float64 scans).

    Every keyframe's scan is read (and checked) again when the SLAM core stores its cloud, so the checks take
    fast paths that decide the same: a scan without NaN is copied whole rather than through a row mask, and
    the per-row count of sub-1e-20 coordinates is made only when some coordinate is that small.
    """
    if len(points) == 0:
        raise InputError(f"{path}: scan has no points")
    nan_rows = np.isnan(points).any(axis=1)
    points = points[~nan_rows] if nan_rows.any() else np.array(points, order="C")  # own, compact memory either way
    if len(points) == 0:
        raise InputError(f"{path}: scan has no finite points")
    magnitude = np.abs(points)
    hint = "; KITTI .bin scans are float32 x, y, z, reflectance" if path.suffix.lower() == ".bin" else ""
    largest = float(magnitude.max())
    if not largest <= MAX_COORDINATE:
        raise InputError(
            f"{path}: coordinate {largest:.3g} m is beyond any sensor's range (|x| <= {MAX_COORDINATE:g} m){hint}"
        )
    small = magnitude < TINY
    tiny = float(((magnitude > 0) & small).any(axis=1).mean()) if small.any() else 0.0
    if tiny > 0.5:
        raise InputError(
            f"{path}: {100 * tiny:.0f} % of the points have coordinates below {TINY:g} m in "
            f"magnitude, which no LiDAR measures{hint}"
        )
    return points


def field_names(dtype: np.dtype) -> tuple[str, ...]:
    """The fields of a point record (a structured dtype: PCD's, a raw format's), in their order."""
    if dtype.names is None:
        raise ValueError(f"{dtype} is not a record of named fields")
    return dtype.names
