"""Keyframe clouds on disk: one downsampled .npy per keyframe, memory-mapped when verification reads it.

Same interface as msa_slam.registration.KeyframeCloudStore (add / [] / in / len / nbytes), so long runs
keep only the keyframe bookkeeping in RAM; `nbytes` is what sits in RAM (zero for clouds on disk) and
`disk_bytes` what the files hold.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Hashable

import numpy as np

from msa_slam.errors import InputError
from msa_slam.io.atomic import atomic_path
from msa_slam.registration import KeyframeCloudStore, downsample


class DiskCloudStore:
    """Downsampled keyframe clouds as `<dir>/kf_<key>.npy` (a temporary folder when `folder` is None)."""

    def __init__(self, voxel_size: float = 0.5, folder: str | os.PathLike | None = None) -> None:
        if not voxel_size > 0:
            raise InputError(f"voxel_size must be > 0, got {voxel_size}")
        self.voxel_size = float(voxel_size)
        self._tmp = None if folder is not None else tempfile.TemporaryDirectory(prefix="msa-kf-clouds-")
        self.folder = Path(folder if folder is not None else self._tmp.name)
        self.folder.mkdir(parents=True, exist_ok=True)
        self._sizes: dict[Hashable, int] = {}

    def _path(self, key: Hashable) -> Path:
        return self.folder / f"kf_{key}.npy"

    def add(self, key: Hashable, points: np.ndarray) -> np.ndarray:
        """Downsample `points`, write them under `key`; return the cloud (not kept in RAM)."""
        cloud = downsample(points, self.voxel_size, where=f"keyframe {key}")
        with atomic_path(self._path(key)) as tmp, open(tmp, "wb") as handle:
            np.save(handle, cloud)
        self._sizes[key] = int(cloud.nbytes)
        return cloud

    def __getitem__(self, key: Hashable) -> np.ndarray:
        if key not in self._sizes:
            raise InputError(f"keyframe {key!r} has no stored cloud")
        return np.load(self._path(key), mmap_mode="r")

    def __contains__(self, key: Hashable) -> bool:
        return key in self._sizes

    def __len__(self) -> int:
        return len(self._sizes)

    @property
    def nbytes(self) -> int:
        """Bytes held in RAM for the clouds: none (they are read from disk on demand)."""
        return 0

    @property
    def disk_bytes(self) -> int:
        """Bytes of point data on disk."""
        return int(sum(self._sizes.values()))

    def close(self) -> None:
        """Remove the folder if it was a temporary one."""
        if self._tmp is not None:
            self._tmp.cleanup()


def make_cloud_store(kind: str, voxel_size: float, folder: str | os.PathLike | None = None):
    """`memory`: KeyframeCloudStore in RAM; `disk`: DiskCloudStore in `folder` (temporary if None)."""
    if kind == "memory":
        return KeyframeCloudStore(voxel_size)
    if kind == "disk":
        return DiskCloudStore(voxel_size, folder)
    raise InputError(f"unknown cloud store {kind!r}; choose memory or disk")
