"""KITTI's HDL-64 vertical-angle correction, as kiss-icp's KITTI loader applies it.

KITTI's Velodyne reports every elevation about 0.2 deg too low (an error of its intrinsic calibration, found by
Deschaud, IMLS-SLAM, ICRA 2018): the flat road bends down with range and distant walls sink, so that LiDAR
odometry on the raw scans drifts, mostly vertically. kiss-icp's KITTI loader therefore turns each point up by
0.205 deg about the horizontal axis perpendicular to it (`_correct_kitti_scan`), and KISS-ICP's published KITTI
figures are on corrected scans. The simulator's "kitti" realism preset gives its scans the same error and records
it in sim.json (sensor.elevation_bias_deg); the KITTI-layout reader corrects such sequences (`needs_correction`),
so that odometry here sees what KISS-ICP sees on real KITTI.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

KISS_ICP_KITTI_DEG = 0.205  # kiss-icp's VERTICAL_ANGLE_OFFSET (kiss_icp_pybind, _correct_kitti_scan)
SIM_META = "sim.json"  # the simulator's record of a sequence, written beside its velodyne/ folder
CORRECTION_NAME = "kiss-icp-kitti-vertical-angle"  # how a corrected sequence says so in cache keys


def raise_elevation(points: np.ndarray, degrees: float = KISS_ICP_KITTI_DEG) -> np.ndarray:
    """`points` (P, >=3) with each x, y, z turned up by `degrees` in its vertical plane (range and azimuth kept;
    kiss-icp's correction, in the points' dtype); points on the z axis, which have no such plane, stay."""
    xyz = points[:, :3].astype(np.float64)
    horizontal = np.hypot(xyz[:, 0], xyz[:, 1])
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    raised = horizontal * c - xyz[:, 2] * s
    scale = np.divide(raised, horizontal, out=np.ones_like(horizontal), where=horizontal > 0)
    out = np.array(points, copy=True)
    out[:, 0] = xyz[:, 0] * scale
    out[:, 1] = xyz[:, 1] * scale
    out[:, 2] = np.where(horizontal > 0, horizontal * s + xyz[:, 2] * c, xyz[:, 2])
    return out


def needs_correction(sequence_dir: Path) -> bool:
    """True when the sequence's sim.json records a sensor elevation error (a simulated KITTI HDL-64); real KITTI
    and other folders carry no such record and are read as they are."""
    try:
        meta = json.loads((Path(sequence_dir) / SIM_META).read_text())
    except (OSError, ValueError):
        return False
    sensor = meta.get("sensor") if isinstance(meta, dict) else None
    return isinstance(sensor, dict) and bool(sensor.get("elevation_bias_deg"))
