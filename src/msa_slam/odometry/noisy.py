"""Ground truth with drift: a cheap stand-in for LiDAR odometry in long or scale runs."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from msa_slam.errors import InputError
from msa_slam.types import validate_poses


class NoisyOdometry:
    """Odometry = ground-truth relative motions, each perturbed: step length scaled by 1 + N(0, t_noise),
    rotation by a random small rotation (std `rotation_noise_deg` per axis). Drift grows as a random walk."""

    def __init__(
        self, gt_poses: np.ndarray, translation_noise: float = 0.01, rotation_noise_deg: float = 0.05, seed: int = 0
    ) -> None:
        if translation_noise < 0 or rotation_noise_deg < 0:
            raise InputError(
                f"gt-noise odometry: noise must be >= 0, got translation_noise={translation_noise}, "
                f"rotation_noise_deg={rotation_noise_deg}"
            )
        self._gt = validate_poses(gt_poses, "gt-noise odometry ground truth")
        self.translation_noise = float(translation_noise)
        self.rotation_noise_deg = float(rotation_noise_deg)
        self.seed = int(seed)
        self._rng = np.random.default_rng(self.seed)
        self._pose: np.ndarray | None = None
        self._frames = 0

    @property
    def config(self) -> dict[str, Any]:
        return {
            "method": "gt_noise",
            "translation_noise": self.translation_noise,
            "rotation_noise_deg": self.rotation_noise_deg,
            "seed": self.seed,
        }

    def register(
        self, points: np.ndarray | None = None, timestamps: np.ndarray | None = None, time: float | None = None
    ) -> np.ndarray:
        """The next odometry pose (the scan itself is not needed)."""
        i = self._frames
        if i >= len(self._gt):
            raise InputError(f"gt-noise odometry: frame {i} requested but the ground truth has {len(self._gt)}")
        if self._pose is None:
            self._pose = self._gt[0].copy()
        else:
            step = np.linalg.inv(self._gt[i - 1]) @ self._gt[i]
            step[:3, 3] *= 1.0 + self._rng.normal(0.0, self.translation_noise)
            noise = np.eye(4)
            noise[:3, :3] = Rotation.from_rotvec(
                np.radians(self._rng.normal(0.0, self.rotation_noise_deg, 3))
            ).as_matrix()
            self._pose = self._pose @ step @ noise
        self._frames += 1
        return self._pose.copy()


class ReplayedOdometry:
    """Odometry poses computed earlier for this sequence, handed out frame by frame; `ms` what computing each
    took (a replayed run counts it), `notes` what that odometry reported of them (frames it could not register),
    for the run's notes."""

    def __init__(self, poses: np.ndarray, ms: np.ndarray, notes: Sequence[str] = ()) -> None:
        self.poses, self.ms, self._i = poses, ms, 0
        self.notes = list(notes)

    def register(
        self, points: np.ndarray | None = None, timestamps: np.ndarray | None = None, time: float | None = None
    ) -> np.ndarray:
        self._i += 1
        return self.poses[self._i - 1]
