"""Spherical range image as the OverlapTransformer authors project it (Ma et al., RA-L 2022).

64 rows for +3..-25 deg pitch, 900 columns for a full turn, -1 where no point lands. Coordinates are
computed in float32 like the authors' pipeline (KITTI .bin scans are float32); points are written
from far to near so the nearest one wins a pixel. Matches ../shared/parity/overlap_transformer_golden.npz
pixel for pixel, except that a point within float32 rounding of a pixel border may land on
either side of it on another CPU (its arctan2 rounds differently).
"""

from __future__ import annotations

import numpy as np

from msa_slam.descriptors.base import validate_points


def projection_coordinates(
    points: np.ndarray,
    fov_up: float = 3.0,
    fov_down: float = -25.0,
    height: int = 64,
    width: int = 900,
    max_range: float = 80.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(row, col, depth) in float32 of the points with depth in (0, max_range), before flooring.

    A point whose row or column lies within float32 rounding of an integer sits on a pixel border:
    another CPU's arctan2/arcsin may put it on either side (tests allow that, nothing else).
    """
    xyz = validate_points(points).astype(np.float32)
    up = fov_up / 180.0 * np.pi
    down = fov_down / 180.0 * np.pi
    fov = abs(down) + abs(up)
    depth = np.linalg.norm(xyz, 2, axis=1)
    keep = (depth > 0) & (depth < max_range)
    xyz, depth = xyz[keep], depth[keep]
    yaw = -np.arctan2(xyz[:, 1], xyz[:, 0])
    pitch = np.arcsin(xyz[:, 2] / depth)
    col = 0.5 * (yaw / np.pi + 1.0) * width
    row = (1.0 - (pitch + abs(down)) / fov) * height
    return row, col, depth


def range_projection(
    points: np.ndarray,
    fov_up: float = 3.0,
    fov_down: float = -25.0,
    height: int = 64,
    width: int = 900,
    max_range: float = 80.0,
) -> np.ndarray:
    """(height, width) float32 range image of a scan; points with depth outside (0, max_range) are dropped."""
    row, col, depth = projection_coordinates(points, fov_up, fov_down, height, width, max_range)
    col = np.clip(np.floor(col), 0, width - 1).astype(np.int32)
    row = np.clip(np.floor(row), 0, height - 1).astype(np.int32)
    order = np.argsort(depth)[::-1]
    image = np.full((height, width), -1.0, dtype=np.float32)
    image[row[order], col[order]] = depth[order]
    return image
