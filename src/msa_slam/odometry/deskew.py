"""Motion compensation of a LiDAR sweep at constant velocity, referred to mid-sweep.

A point fired at sweep fraction s (0 = first point, 1 = last) was measured in the sensor frame of that
instant; with the sensor moving by the SE(3) twist xi over the sweep, its coordinates in the frame of
mid-sweep are exp((s - 0.5) xi) p. KISS-ICP 1.3 refers the same correction to the sweep's end
(exp((s - 1) xi) p); mid-sweep is when KITTI's (and the simulator's) scan timestamps and ground truth are
taken. Closed forms (Rodrigues and the SE(3) left Jacobian), vectorised over the points.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

SMALL_ANGLE = 1e-9  # rad: below it the rotation's series terms vanish (pure translation)


def _hat(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def se3_log(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rho, phi): the twist whose exponential is the rigid transform `pose` (4, 4); phi the rotation vector."""
    phi = Rotation.from_matrix(pose[:3, :3]).as_rotvec()
    theta = float(np.linalg.norm(phi))
    if theta < SMALL_ANGLE:
        return pose[:3, 3].copy(), phi
    k = _hat(phi / theta)
    left_jacobian = np.eye(3) + (1 - np.cos(theta)) / theta * k + (1 - np.sin(theta) / theta) * k @ k
    return np.linalg.solve(left_jacobian, pose[:3, 3]), phi


def deskew(points: np.ndarray, fractions: np.ndarray, rho: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """`points` (P, 3), each fired at sweep fraction `fractions` (P,) in [0, 1], in the sensor frame of
    mid-sweep: exp((s - 0.5) xi) p for the sweep's twist xi = (rho, phi) (see se3_log)."""
    a = (np.asarray(fractions, dtype=np.float64) - 0.5)[:, None]
    theta = float(np.linalg.norm(phi))
    if theta < SMALL_ANGLE:
        return points + a * rho
    k = _hat(phi / theta)
    angle = a * theta
    sin, one_minus_cos = np.sin(angle), 1.0 - np.cos(angle)
    kp, kkp = points @ k.T, points @ (k @ k).T
    kr, kkr = k @ rho, k @ k @ rho
    rotated = points + sin * kp + one_minus_cos * kkp
    return rotated + a * rho + one_minus_cos / theta * kr + (angle - sin) / theta * kkr
