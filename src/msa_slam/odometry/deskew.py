"""Motion compensation of a LiDAR sweep at constant velocity, referred to mid-sweep.

A point fired at sweep fraction s (0 = first point, 1 = last) was measured in the sensor frame of that
instant; with the sensor moving by the SE(3) twist xi over the sweep, its coordinates in the frame of
mid-sweep are exp((s - 0.5) xi) p. KISS-ICP 1.3 refers the same correction to the sweep's end
(exp((s - 1) xi) p); mid-sweep is when KITTI's (and the simulator's) scan timestamps and ground truth are
taken. The twist is GTSAM's Pose3 logarithm; the exponential, one a point, is the closed form written here (Rodrigues'
rotation and the SO(3) left Jacobian), compiled with numba in one pass over the points: it runs on the odometry's
critical path for every scan, and scipy's Rotation (a quaternion and a matrix per point) plus numpy's whole-array
passes cost ten times as much (why kept by hand: docs/architecture.md).
"""

from __future__ import annotations

import gtsam
import numba
import numpy as np

SMALL_ANGLE = 1e-9  # rad: below it the rotation's series terms vanish (pure translation)


def se3_log(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rho, phi): the twist whose exponential is the rigid transform `pose` (4, 4); phi the rotation vector."""
    xi = gtsam.Pose3.Logmap(gtsam.Pose3(np.asarray(pose, dtype=np.float64)))  # GTSAM's order: rotation first
    return xi[3:], xi[:3]


def deskew(points: np.ndarray, fractions: np.ndarray, rho: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """`points` (P, 3), each fired at sweep fraction `fractions` (P,) in [0, 1], in the sensor frame of
    mid-sweep: exp((s - 0.5) xi) p for the sweep's twist xi = (rho, phi) (see se3_log)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    shares = np.ascontiguousarray(fractions, dtype=np.float64) - 0.5
    rho, phi = np.asarray(rho, dtype=np.float64), np.asarray(phi, dtype=np.float64)
    theta = float(np.linalg.norm(phi))
    if theta < SMALL_ANGLE:
        return points + shares[:, None] * rho
    k = phi / theta
    return _exp_apply(points, shares, rho, k, theta, np.cross(k, rho), np.cross(k, np.cross(k, rho)))


@numba.njit(cache=True)
def _exp_apply(
    points: np.ndarray,
    shares: np.ndarray,
    rho: np.ndarray,
    k: np.ndarray,
    theta: float,
    kr: np.ndarray,
    kkr: np.ndarray,
) -> np.ndarray:
    """exp(a xi) p for each point's share a: Rodrigues' rotation by a theta about the unit axis k, then the
    translation V(a phi) a rho = a rho + (1 - cos a theta) / theta (k x rho) + (a theta - sin a theta) / theta
    (k x (k x rho))."""
    out = np.empty_like(points)
    for i in range(points.shape[0]):
        a = shares[i]
        angle = a * theta
        c, s = np.cos(angle), np.sin(angle)
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        kdotp = k[0] * x + k[1] * y + k[2] * z
        cross = (k[1] * z - k[2] * y, k[2] * x - k[0] * z, k[0] * y - k[1] * x)
        bend, sweep = (1.0 - c) / theta, (angle - s) / theta
        for j in range(3):
            rotated = points[i, j] * c + cross[j] * s + k[j] * kdotp * (1.0 - c)
            out[i, j] = rotated + a * rho[j] + bend * kr[j] + sweep * kkr[j]
    return out
