"""Scans that see (almost) nothing, caught as early as each can be: a max_range too short to reach the ground
before the world is built, an empty scan as soon as it is cast (msa-slam's readers refuse a sequence holding
one, datasets.clouds.check_bin_size), and scans too sparse to register in one warning once all are written."""

from __future__ import annotations

import math
import warnings

import numpy as np

from msa_slam.errors import InputError
from msa_slam.sim.config import SimConfig
from msa_slam.sim.sensors import SENSORS, LidarModel

SPARSE_SCAN_POINTS = 100  # a scan with fewer points is too sparse for KISS-ICP and Scan Context to work with
POINT_BYTES = 16  # a scan file's point: float32 x, y, z, intensity


def check_reaches_ground(model: LidarModel, height: float) -> None:
    """Refuse a max_range shorter than the lowest beam's way down to flat ground `height` metres below the
    sensor: the ground is most of every scan, so without it scans hold only objects nearer than max_range,
    which the worlds keep off the road (every scan empty)."""
    lowest = min(model.elevations_deg)
    if lowest >= 0:  # no beam points down: the ground sets no minimum
        return
    reach = height / math.sin(math.radians(-lowest))
    if model.max_range < reach:
        raise InputError(f"simulation config: max_range={model.max_range:g} m is shorter than the {reach:.1f} m at "
                         f"which the lowest beam of {model.name} ({lowest:g} deg) meets the ground from {height:g} m "
                         f"up, so the scans would be empty; give max_range >= {math.ceil(reach)} m or leave it unset "
                         f"(the sensor's default)")


def likely_settings(config: SimConfig) -> str:
    """The settings of `config` that thin the scans below the sensor's defaults, as advice for a message."""
    default = SENSORS[config.sensor]
    thinning = []
    if config.max_range is not None and config.max_range < default.max_range:
        thinning.append(f"max_range={config.max_range:g} m")
    if config.dropout > 0:
        thinning.append(f"dropout={config.dropout:g}")
    if config.azimuth_steps is not None and config.azimuth_steps < default.azimuth_steps:
        thinning.append(f"azimuth_steps={config.azimuth_steps}")
    if not thinning:
        return "no setting thins them: the sensor sees little around this trajectory"
    return f"check {', '.join(thinning)}"


def empty_scan_error(config: SimConfig, k: int, frames: int) -> InputError:
    """The error for scan k of `frames` having no points (raised before the sequence is written)."""
    return InputError(f"simulate: scan {k} of {frames} has no points, and msa-slam cannot read a sequence with an "
                      f"empty scan; {likely_settings(config)} (nothing was written)")


def warn_sparse_scans(config: SimConfig, scan_bytes: list[int]) -> None:
    """One warning when some scans (sizes in bytes) hold fewer than SPARSE_SCAN_POINTS points."""
    points = np.asarray(scan_bytes, dtype=np.int64) // POINT_BYTES
    sparse = int((points < SPARSE_SCAN_POINTS).sum())
    if sparse:
        warnings.warn(f"simulate: {sparse} of {len(points)} scans have fewer than {SPARSE_SCAN_POINTS} points "
                      f"(fewest {points.min()}), too few for odometry and descriptors; {likely_settings(config)}",
                      UserWarning, stacklevel=3)
