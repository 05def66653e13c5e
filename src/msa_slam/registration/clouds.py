"""Downsampled keyframe clouds in memory (what loop verification keeps) and the voxel downsampling they share."""

from __future__ import annotations

from collections.abc import Hashable

import numpy as np
import small_gicp

from msa_slam.errors import InputError
from msa_slam.types import as_points


def downsample(points: np.ndarray, voxel_size: float, where: str = "points") -> np.ndarray:
    """Voxel-grid centroids (small_gicp) as a (P', 3) float32 array: the stored form of a keyframe cloud."""
    if not voxel_size > 0:
        raise InputError(f"voxel_size must be > 0, got {voxel_size}")
    cloud = small_gicp.voxelgrid_sampling(as_points(points, where), float(voxel_size))
    return np.asarray(cloud.points()[:, :3], dtype=np.float32)


class KeyframeCloudStore:
    """Downsampled keyframe clouds by key, with their accounted memory (bytes of the stored arrays)."""

    def __init__(self, voxel_size: float = 0.5) -> None:
        if not voxel_size > 0:
            raise InputError(f"voxel_size must be > 0, got {voxel_size}")
        self.voxel_size = float(voxel_size)
        self._clouds: dict[Hashable, np.ndarray] = {}

    def add(self, key: Hashable, points: np.ndarray) -> np.ndarray:
        """Downsample and keep `points` under `key` (replacing any earlier cloud); return the stored array."""
        return self.keep(key, downsample(points, self.voxel_size, where=f"keyframe {key}"))

    def keep(self, key: Hashable, cloud: np.ndarray) -> np.ndarray:
        """Keep `cloud`, already downsampled at this store's voxel size (cloud_cache.FrameClouds), under `key`."""
        self._clouds[key] = cloud
        return cloud

    def __getitem__(self, key: Hashable) -> np.ndarray:
        try:
            return self._clouds[key]
        except KeyError:
            raise InputError(f"keyframe {key!r} has no stored cloud") from None

    def __contains__(self, key: Hashable) -> bool:
        return key in self._clouds

    def __len__(self) -> int:
        return len(self._clouds)

    @property
    def nbytes(self) -> int:
        """Accounted memory: bytes of all stored point arrays."""
        return int(sum(c.nbytes for c in self._clouds.values()))
