"""Voxel-centroid downsampling in one O(N) hash pass (numba), as the Scan Context authors' open3d step.

The grid is anchored at the cloud's minimum corner and each occupied voxel is replaced by the mean of
its points (accumulated in input order, float64). This reproduces the downsampled KITTI clouds in
../shared/parity/scan_context_kitti00.npz point for point; a sort-based np.unique takes ~20 ms per
scan, this pass a few.
"""

from __future__ import annotations

import numba
import numpy as np

from msa_slam.errors import InputError

_EMPTY = -1
_FIB = 11400714819323198485  # 2^64 / golden ratio: Fibonacci hashing, table index from the top bits


@numba.njit(cache=True)
def _slot(slot_key: np.ndarray, key: int, bits: int) -> int:
    """Linear-probing slot of `key` (its own or the first empty one)."""
    s = np.int64((np.uint64(key) * np.uint64(_FIB)) >> np.uint64(64 - bits))
    mask = (1 << bits) - 1
    while slot_key[s] != _EMPTY and slot_key[s] != key:
        s = (s + 1) & mask
    return s


@numba.njit(cache=True, nogil=True)  # nogil: run in a reader thread (a bag's front end) beside the odometry
def _voxel_centroids(xyz: np.ndarray, voxel: float) -> tuple[np.ndarray, int]:
    """(centroids, -1), or (empty, i) when point i is not finite. Works on float32/64 views in place."""
    n = xyz.shape[0]
    mn = np.empty(3)
    mx = np.empty(3)
    for a in range(3):
        mn[a] = np.float64(xyz[0, a])
        mx[a] = mn[a]
    for i in range(n):
        for a in range(3):
            c = np.float64(xyz[i, a])
            if not np.isfinite(c):
                return np.empty((0, 3)), i
            mn[a] = min(mn[a], c)
            mx[a] = max(mx[a], c)
    ny = np.int64(np.floor((mx[1] - mn[1]) / voxel)) + 1
    nz = np.int64(np.floor((mx[2] - mn[2]) / voxel)) + 1
    # Small table (cache resident), doubled whenever it gets half full.
    bits = 10
    while (1 << bits) < n // 4:
        bits += 1
    slot_key = np.full(1 << bits, _EMPTY, dtype=np.int64)
    slot_voxel = np.empty(1 << bits, dtype=np.int64)
    # Accumulators sized like the table (not like the cloud): fewer pages to touch.
    sums = np.zeros((1 << (bits - 1), 3))
    counts = np.zeros(1 << (bits - 1), dtype=np.int64)
    n_vox = 0
    last_key = _EMPTY
    v = 0
    for i in range(n):
        x = np.float64(xyz[i, 0])
        y = np.float64(xyz[i, 1])
        z = np.float64(xyz[i, 2])
        ix = np.int64(np.floor((x - mn[0]) / voxel))
        iy = np.int64(np.floor((y - mn[1]) / voxel))
        iz = np.int64(np.floor((z - mn[2]) / voxel))
        key = (ix * ny + iy) * nz + iz
        if key != last_key:  # scans are ordered, so runs of points share a voxel
            s = _slot(slot_key, key, bits)
            if slot_key[s] == _EMPTY:
                if 2 * (n_vox + 1) > (1 << bits):
                    old_key, old_voxel = slot_key, slot_voxel
                    bits += 1
                    slot_key = np.full(1 << bits, _EMPTY, dtype=np.int64)
                    slot_voxel = np.empty(1 << bits, dtype=np.int64)
                    for t in range(old_key.shape[0]):
                        if old_key[t] != _EMPTY:
                            r = _slot(slot_key, old_key[t], bits)
                            slot_key[r] = old_key[t]
                            slot_voxel[r] = old_voxel[t]
                    s = _slot(slot_key, key, bits)
                    grown_sums = np.zeros((1 << (bits - 1), 3))
                    grown_sums[:n_vox] = sums[:n_vox]
                    grown_counts = np.zeros(1 << (bits - 1), dtype=np.int64)
                    grown_counts[:n_vox] = counts[:n_vox]
                    sums, counts = grown_sums, grown_counts
                slot_key[s] = key
                slot_voxel[s] = n_vox
                n_vox += 1
            v = slot_voxel[s]
            last_key = key
        sums[v, 0] += x
        sums[v, 1] += y
        sums[v, 2] += z
        counts[v] += 1
    out = np.empty((n_vox, 3))
    for w in range(n_vox):
        for a in range(3):
            out[w, a] = sums[w, a] / counts[w]
    return out, -1


def voxel_downsample(points: np.ndarray, voxel_size: float = 0.5) -> np.ndarray:
    """Centroid of each occupied `voxel_size` voxel (grid anchored at the cloud's min corner), (V, 3) float64."""
    if not voxel_size > 0:
        raise InputError(f"voxel_size: must be > 0, got {voxel_size}")
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] < 3:
        raise InputError(f"points: expected shape (P, 3) or (P, 4), got {arr.shape}")
    if arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float64)
    if len(arr) == 0:
        return np.zeros((0, 3))
    out, bad = _voxel_centroids(arr[:, :3], float(voxel_size))
    if bad >= 0:
        raise InputError(f"points: point {bad} has NaN or infinite coordinates")
    return out
