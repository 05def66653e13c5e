"""The run's map: every keyframe's stored (downsampled) cloud placed at its optimised pose and merged on one
voxel grid, so a user can look at what the SLAM built (KISS-SLAM writes its local maps the same way)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from msa_slam.registration import downsample
from msa_slam.slam.keyframes import CloudStore

CHUNK_POINTS = 2_000_000  # merge on the grid every ~2 M points: memory stays bounded on long sequences


def keyframe_map(
    clouds: CloudStore, keys: Sequence[int] | np.ndarray, poses: np.ndarray, voxel_size: float
) -> np.ndarray:
    """(P, 3) float32 world points: cloud of keyframe keys[i] transformed by poses[i], voxel-downsampled."""
    merged = np.zeros((0, 3), dtype=np.float32)
    pending: list[np.ndarray] = []
    size = 0
    for key, pose in zip(keys, poses):
        local = np.asarray(clouds[int(key)], dtype=np.float64)
        pending.append((local @ pose[:3, :3].T + pose[:3, 3]).astype(np.float32))
        size += len(local)
        if size >= CHUNK_POINTS:
            merged = downsample(np.concatenate([merged, *pending]), voxel_size, where="map")
            pending, size = [], 0
    if pending:
        merged = downsample(np.concatenate([merged, *pending]), voxel_size, where="map")
    return merged
