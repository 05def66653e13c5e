"""Which way is up in a trajectory's frame, so that the world can be built upright.

KITTI's ground truth starts from the first camera pose, which is not level: the frame's z axis leans against
gravity by the car's attitude at its first frame (KITTI-09 starts on a climb). A world built along that z axis
has every building and pole leaning by as much, and roads level across in a frame that is not.

Gravity is read from the sensor's own z axis along the drive. Its component along the direction of travel says
nothing about gravity (the car's up is perpendicular to its velocity in any frame: a climb tips it back exactly
as much as the path rises), so a hill climbed in one direction would bias a fit that used it. Its component
across the direction of travel is the car's roll (cross-fall, the sensor's mounting) plus the frame's tilt seen
from that heading: a sinusoid in the heading, whose amplitude and phase are the tilt. A drive that keeps one
heading cannot tell the tilt; it is then taken as level.
"""

from __future__ import annotations

import numpy as np

from msa_slam.types import validate_poses

MIN_SPEED_MPS = 1.0  # a standing car's heading is noise: such frames do not count
MIN_HEADING_SPREAD = 0.01  # smallest eigenvalue of the lateral axes' covariance: a straight drive 0, KITTI-06 (driven
# to and fro along one street, turning at its ends) 0.046, the other shipped KITTI drives 0.35-0.43
LEVEL_DEG = 1e-4  # tilts below this are a level trajectory's rounding


def _lateral_axes(poses: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit horizontal axes across the direction of travel (left of it) of the moving frames, and the sensor's
    z axis along them."""
    velocity = np.gradient(poses[:, :3, 3], times, axis=0)
    horizontal = np.linalg.norm(velocity[:, :2], axis=1)
    moving = horizontal > MIN_SPEED_MPS
    heading = velocity[moving, :2] / horizontal[moving, None]
    lateral = np.column_stack([-heading[:, 1], heading[:, 0]])
    return lateral, np.einsum("ij,ij->i", poses[moving, :2, 2], lateral)


def gravity_up(poses: np.ndarray, times: np.ndarray | None = None) -> np.ndarray:
    """Unit up vector of gravity in the frame of `poses` (N, 4, 4, world-from-sensor of a ground vehicle; times
    in s, default 10 Hz), least squares over the lateral component of the sensor's z axis; (0, 0, 1) when the
    drive's headings do not vary enough to tell."""
    poses = validate_poses(poses, "trajectory")
    times = np.arange(len(poses)) / 10.0 if times is None else np.asarray(times, dtype=np.float64)
    if len(poses) < 3:
        return np.array([0.0, 0.0, 1.0])
    lateral, z_across = _lateral_axes(poses, times)
    if len(lateral) < 3 or np.linalg.eigvalsh(np.cov(lateral.T))[0] < MIN_HEADING_SPREAD:
        return np.array([0.0, 0.0, 1.0])
    design = np.column_stack([lateral, np.ones(len(lateral))])  # tilt x, tilt y, mean roll
    (tilt_x, tilt_y, _), *_ = np.linalg.lstsq(design, z_across, rcond=None)
    up = np.array([tilt_x, tilt_y, 1.0])
    return up / np.linalg.norm(up)


def tilt_deg(up: np.ndarray) -> float:
    """Angle in degrees between `up` and the frame's z axis."""
    up = np.asarray(up, dtype=np.float64)
    return float(np.degrees(np.arctan2(np.linalg.norm(up[:2]), up[2])))


def levelling_rotation(up: np.ndarray) -> np.ndarray:
    """The (3, 3) rotation taking unit `up` to (0, 0, 1) about the horizontal axis perpendicular to it (no turn
    about the vertical), so the levelled frame keeps the trajectory's headings."""
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    axis = np.cross(up, [0.0, 0.0, 1.0])
    s, c = np.linalg.norm(axis), up[2]
    if s < 1e-15:
        if c > 0:
            return np.eye(3)
        raise ValueError("levelling_rotation: up points down")
    k = axis / s
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * cross + (1.0 - c) * cross @ cross
