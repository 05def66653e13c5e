"""Scans that see (almost) nothing, caught as early as each can be: a max_range too short to reach the ground
before the world is built, an empty scan as soon as it is cast (msa-slam's readers refuse a sequence holding
one, datasets.clouds.check_bin_size), a max_range too short for odometry in one warning before the world is
built, and scans too sparse to register in one warning once all are written."""

from __future__ import annotations

import math
import warnings

import numpy as np

from msa_slam.errors import InputError
from msa_slam.sim.config import SimConfig
from msa_slam.sim.sensors import SENSORS, LidarModel

SPARSE_SCAN_POINTS = 200  # a scan with fewer points is too sparse for KISS-ICP to register (warn_sparse_scans)
POINT_BYTES = 16  # a scan file's point: float32 x, y, z, intensity
SHORT_RANGE_M = 15.0  # a max_range below this leaves KISS-ICP too little structure to register (warn_short_range)


def check_reaches_ground(model: LidarModel, height: float) -> None:
    """Refuse a max_range shorter than the lowest beam's way down to flat ground `height` metres below the
    sensor: the ground is most of every scan, so without it scans hold only objects nearer than max_range,
    which the worlds keep off the road (every scan empty)."""
    lowest = min(model.elevations_deg)
    if lowest >= 0:  # no beam points down: the ground sets no minimum
        return
    reach = height / math.sin(math.radians(-lowest))
    if model.max_range < reach:
        raise InputError(
            f"simulation config: max_range={model.max_range:g} m is shorter than the {reach:.1f} m at "
            f"which the lowest beam of {model.name} ({lowest:g} deg) meets the ground from {height:g} m "
            f"up, so the scans would be empty; give max_range >= {math.ceil(reach)} m or leave it unset "
            f"(the sensor's default)"
        )


def warn_short_range(config: SimConfig) -> None:
    """One warning (before the world is built, and when the sequence is reused) for a max_range under
    SHORT_RANGE_M: the scans then hold the ground and the nearest objects only, and odometry fails however many
    points they have. Measured (hdl64, kitti-05, 50 frames = 40 m, about 100,000 points a scan, KISS-ICP
    odometry ATE): 0.03 m at the sensor's 120 m, 0.17 at 20 m, 0.21 at 15 m, 0.68 at 12 m, 3.9 at 10 m, 11.5 at
    4.5 m."""
    if config.max_range is not None and config.max_range < SHORT_RANGE_M:
        warnings.warn(
            f"simulate: max_range={config.max_range:g} m leaves the scans only the ground and the nearest "
            f"objects; odometry fails on them below about {SHORT_RANGE_M:g} m",
            UserWarning,
            stacklevel=3,
        )


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
    return InputError(
        f"simulate: scan {k} of {frames} has no points, and msa-slam cannot read a sequence with an "
        f"empty scan; {likely_settings(config)} (nothing was written)"
    )


def warn_sparse_scans(config: SimConfig, scan_bytes: list[int]) -> None:
    """One warning when some scans (sizes in bytes) hold fewer than SPARSE_SCAN_POINTS points.

    Why 200: thinned by dropout (hdl64, kitti-05, full range, 50 frames, 40 m), KISS-ICP's odometry ATE is
    0.03 m at 11,000 points a scan and stays within 0.5 % of the path down to about 200 (0.10-0.20 m), then
    reaches ten times the dense value by 100 (0.3-0.4 m) and breaks down below 50 (2.7 m). Scans cut by a short
    max_range are another matter, which no number of points tells: at 4.5-10 m odometry fails (ATE 3.6-11.8 m)
    with 1,400 to 60,000 points a scan, as they hold only the ground and the nearest objects.
    """
    points = np.asarray(scan_bytes, dtype=np.int64) // POINT_BYTES
    sparse = int((points < SPARSE_SCAN_POINTS).sum())
    if sparse:
        warnings.warn(
            f"simulate: {sparse} of {len(points)} scans have fewer than {SPARSE_SCAN_POINTS} points "
            f"(fewest {points.min()}), too few for odometry and descriptors; {likely_settings(config)}",
            UserWarning,
            stacklevel=3,
        )
