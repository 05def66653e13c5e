"""Motion compensation of a LiDAR sweep at constant velocity, referred to mid-sweep.

A point fired at sweep fraction s (0 = first point, 1 = last) was measured in the sensor frame of that
instant; with the sensor moving by the SE(3) twist xi over the sweep, its coordinates in the frame of
mid-sweep are exp((s - 0.5) xi) p. KISS-ICP 1.3 refers the same correction to the sweep's end
(exp((s - 1) xi) p); mid-sweep is when KITTI's (and the simulator's) scan timestamps and ground truth are
taken. The twist is GTSAM's Pose3 logarithm, the rotations scipy's; the translations of the exponential, one a
point, are the closed form written here (why: docs/architecture.md, hand-written code kept).
"""

from __future__ import annotations

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

SMALL_ANGLE = 1e-9  # rad: below it the rotation's series terms vanish (pure translation)


def se3_log(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rho, phi): the twist whose exponential is the rigid transform `pose` (4, 4); phi the rotation vector."""
    xi = gtsam.Pose3.Logmap(gtsam.Pose3(np.asarray(pose, dtype=np.float64)))  # GTSAM's order: rotation first
    return xi[3:], xi[:3]


def deskew(points: np.ndarray, fractions: np.ndarray, rho: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """`points` (P, 3), each fired at sweep fraction `fractions` (P,) in [0, 1], in the sensor frame of
    mid-sweep: exp((s - 0.5) xi) p for the sweep's twist xi = (rho, phi) (see se3_log)."""
    a = (np.asarray(fractions, dtype=np.float64) - 0.5)[:, None]
    theta = float(np.linalg.norm(phi))
    if theta < SMALL_ANGLE:
        return points + a * rho
    rotated = Rotation.from_rotvec(a * phi).apply(points)
    # translation of exp(a xi): V(a phi) a rho, V the SO(3) left Jacobian (Rodrigues' series, axis k = phi / theta)
    k = phi / theta
    angle = a * theta
    kr, kkr = np.cross(k, rho), np.cross(k, np.cross(k, rho))
    return rotated + a * rho + (1.0 - np.cos(angle)) / theta * kr + (angle - np.sin(angle)) / theta * kkr
