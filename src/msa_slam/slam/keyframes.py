"""The keyframe store: what SLAM keeps of each keyframe (odometry pose, descriptor, downsampled cloud) and
the bytes it accounts for, the memory figure the samplers are compared on."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from msa_slam.descriptors import Descriptor
from msa_slam.place_recognition import KeyframeDatabase


class CloudStore(Protocol):
    """Downsampled keyframe clouds by frame index (msa_slam.registration: in memory or on disk)."""

    def add(self, key: int, points: np.ndarray) -> np.ndarray: ...
    def keep(self, key: int, cloud: np.ndarray) -> np.ndarray: ...
    def __getitem__(self, key: int) -> np.ndarray: ...
    @property
    def nbytes(self) -> int: ...


class KeyframeStore:
    """Keyframes in the order they were added: poses and descriptors in a searchable database, clouds in
    `clouds`. `add_cloud` and `add` are separate so a keyframe's cloud is stored before it queries the
    database of the keyframes before it."""

    def __init__(self, descriptor: Descriptor, clouds: CloudStore) -> None:
        self.descriptor = descriptor
        self.database = KeyframeDatabase(descriptor)
        self.clouds = clouds
        self._row: dict[int, int] = {}

    def __len__(self) -> int:
        return len(self._row)

    def add_cloud(self, frame: int, points: np.ndarray) -> None:
        self.clouds.add(frame, points)

    def keep_cloud(self, frame: int, cloud: np.ndarray) -> None:
        """Store a cloud already downsampled at the clouds' voxel size (the front end's FrameClouds)."""
        self.clouds.keep(frame, cloud)

    def add(self, frame: int, pose: np.ndarray, descriptor: np.ndarray) -> None:
        """Enter a keyframe (its cloud already stored) into the database that later keyframes query."""
        self._row[frame] = len(self.database)
        self.database.add(frame, pose, descriptor)

    def descriptor_of(self, frame: int) -> np.ndarray:
        return self.database.descriptors[self._row[frame]]

    def cloud(self, frame: int) -> np.ndarray:
        return self.clouds[frame]

    @property
    def cloud_bytes(self) -> int:
        """Cloud bytes held in RAM (zero for clouds on disk)."""
        return int(self.clouds.nbytes)

    @property
    def disk_bytes(self) -> int:
        """Cloud bytes held on disk (zero for clouds in RAM)."""
        return int(getattr(self.clouds, "disk_bytes", 0))

    @property
    def descriptor_bytes(self) -> int:
        return int(self.database.nbytes)

    def close(self) -> None:
        """Release the clouds (a disk store removes its files); safe to call twice."""
        close = getattr(self.clouds, "close", None)
        if close is not None:
            close()
