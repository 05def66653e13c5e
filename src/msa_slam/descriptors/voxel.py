"""Voxel-centroid downsampling in one O(N) hash pass (numba), as the Scan Context authors' open3d step.

The grid is anchored at the cloud's minimum corner and each occupied voxel is replaced by the mean of
its points (accumulated in input order, float64). This reproduces the downsampled KITTI clouds in
../shared/parity/scan_context_kitti00.npz point for point; a sort-based np.unique takes ~20 ms per
scan, this pass a few.
"""

from __future__ import annotations

import numba
import numpy as np

from msa_slam.descriptors.base import validate_points
from msa_slam.errors import InputError

_EMPTY = -1


@numba.njit(cache=True)
def _voxel_centroids(xyz: np.ndarray, voxel: float) -> np.ndarray:
    n = xyz.shape[0]
    mn = np.empty(3)
    mx = np.empty(3)
    for a in range(3):
        mn[a] = xyz[0, a]
        mx[a] = xyz[0, a]
    for i in range(n):
        for a in range(3):
            v = xyz[i, a]
            if v < mn[a]:
                mn[a] = v
            if v > mx[a]:
                mx[a] = v
    ny = np.int64(np.floor((mx[1] - mn[1]) / voxel)) + 1
    nz = np.int64(np.floor((mx[2] - mn[2]) / voxel)) + 1
    cap = 1
    while cap < 2 * n:
        cap *= 2
    mask = np.uint64(cap - 1)
    slot_key = np.full(cap, _EMPTY, dtype=np.int64)
    slot_voxel = np.empty(cap, dtype=np.int64)
    sums = np.zeros((n, 3))
    counts = np.zeros(n, dtype=np.int64)
    n_vox = 0
    for i in range(n):
        ix = np.int64(np.floor((xyz[i, 0] - mn[0]) / voxel))
        iy = np.int64(np.floor((xyz[i, 1] - mn[1]) / voxel))
        iz = np.int64(np.floor((xyz[i, 2] - mn[2]) / voxel))
        key = (ix * ny + iy) * nz + iz
        h = (np.uint64(key) * np.uint64(11400714819323198485)) >> np.uint64(20)
        s = np.int64(h & mask)
        while slot_key[s] != _EMPTY and slot_key[s] != key:
            s = (s + 1) & (cap - 1)
        if slot_key[s] == _EMPTY:
            slot_key[s] = key
            slot_voxel[s] = n_vox
            n_vox += 1
        v = slot_voxel[s]
        for a in range(3):
            sums[v, a] += xyz[i, a]
        counts[v] += 1
    out = np.empty((n_vox, 3))
    for v in range(n_vox):
        for a in range(3):
            out[v, a] = sums[v, a] / counts[v]
    return out


def voxel_downsample(points: np.ndarray, voxel_size: float = 0.5) -> np.ndarray:
    """Centroid of each occupied `voxel_size` voxel (grid anchored at the cloud's min corner), (V, 3) float64."""
    if not voxel_size > 0:
        raise InputError(f"voxel_size: must be > 0, got {voxel_size}")
    xyz = validate_points(points)
    if len(xyz) == 0:
        return np.zeros((0, 3))
    return _voxel_centroids(xyz, float(voxel_size))
