"""LiDAR odometry with KISS-ICP (Vizzo et al., RA-L 2023), or odometry read from a pose file."""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from kiss_icp.config import load_config
from kiss_icp.kiss_icp import KissICP

from msa_slam.errors import InputError
from msa_slam.io.poses import read_poses
from msa_slam.registration.clouds import as_points


class KissOdometry:
    """KISS-ICP with its own defaults; `register(points)` returns the world-from-LiDAR pose of that scan.

    Deskewing is off by default (scans without per-point times); the voxel size follows KISS-ICP's rule
    max_range / 100 unless given.
    """

    def __init__(self, max_range: float = 100.0, min_range: float = 0.0, voxel_size: float | None = None,
                 deskew: bool = False, num_threads: int = 0) -> None:
        if not 0 <= min_range < max_range:
            raise InputError(f"KISS-ICP needs 0 <= min_range < max_range, got {min_range} and {max_range}")
        if voxel_size is not None and not voxel_size > 0:
            raise InputError(f"KISS-ICP voxel_size must be > 0, got {voxel_size}")
        config = load_config(None)
        config.data.max_range = float(max_range)
        config.data.min_range = float(min_range)
        config.data.deskew = bool(deskew)
        config.mapping.voxel_size = float(voxel_size if voxel_size is not None else max_range / 100.0)
        config.registration.max_num_threads = int(num_threads)
        self._icp = KissICP(config)
        self._frames = 0

    @property
    def config(self) -> dict[str, Any]:
        """The effective KISS-ICP configuration (identifies cached results)."""
        settings = self._icp.config.model_dump()
        settings.pop("out_dir", None)
        settings["registration"].pop("max_num_threads", None)  # threads do not change the result
        return {"method": "kiss_icp", **settings}

    def register(self, points: np.ndarray, timestamps: np.ndarray | None = None) -> np.ndarray:
        """Register the next scan (sensor frame); return its (4, 4) world-from-LiDAR pose."""
        cloud = as_points(points, where=f"odometry frame {self._frames}")
        stamps = np.zeros(0) if timestamps is None else np.asarray(timestamps, dtype=np.float64).ravel()
        self._icp.register_frame(cloud, stamps)
        self._frames += 1
        return np.array(self._icp.last_pose, dtype=np.float64)


class PosesFromFile:
    """Odometry taken from a KITTI or TUM pose file: frame i gets line i."""

    def __init__(self, path: str | os.PathLike, fmt: str = "auto") -> None:
        self.path = os.fspath(path)
        self.poses, self.times = read_poses(path, fmt)
        self._frames = 0

    @property
    def config(self) -> dict[str, Any]:
        return {"method": "pose_file", "path": os.path.abspath(self.path)}

    def __len__(self) -> int:
        return len(self.poses)

    def register(self, points: np.ndarray | None = None, timestamps: np.ndarray | None = None) -> np.ndarray:
        """Return the next pose of the file (the scan itself is not needed)."""
        if self._frames >= len(self.poses):
            raise InputError(f"{self.path}: has {len(self.poses)} poses but frame {self._frames} was requested")
        pose = self.poses[self._frames].copy()
        self._frames += 1
        return pose
