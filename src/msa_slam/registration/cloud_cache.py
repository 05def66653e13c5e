"""Every frame's downsampled cloud, the form the keyframe store keeps, computed once per sequence and voxel size
and cached on disk by the scans' identity and the code that computes them (CLOUD_CODE).

A keyframe's cloud depends on its scan and the voxel size alone, not on the sampler, so it belongs to the shared
front end: each sampler's back end then copies its keyframes' clouds instead of reading, correcting and
voxelising their scans again (on simulated KITTI-07 that was ~37 ms per keyframe, most of a back end's time).
The entry is two arrays, the clouds concatenated (M, 3) float32 and where each frame's starts (N + 1,) int64;
the points are memory-mapped, so a run holds in RAM only the keyframes' clouds it copies.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from msa_slam.datasets import ScanSequence
from msa_slam.io.cache import CacheDir, cache_key, sequence_inputs
from msa_slam.io.fingerprint import code_fingerprint

CLOUD_LIBRARIES = ("numpy", "small_gicp")
CLOUD_CODE = ("msa_slam.registration.clouds", "msa_slam.datasets")  # the voxel downsampling and the scan readers


class CloudsByFrame(Protocol):
    """Frame i's downsampled cloud by index, a copy (FrameClouds, or the clouds received so far while a front end
    computes them: pipeline.streamed)."""

    @property
    def voxel_size(self) -> float: ...
    def __getitem__(self, frame: int) -> np.ndarray: ...


@dataclass(frozen=True)
class FrameClouds:
    """Frame i's downsampled cloud is points[offsets[i]:offsets[i + 1]] (voxel centroids at `voxel_size`)."""

    points: np.ndarray
    offsets: np.ndarray
    voxel_size: float

    def __len__(self) -> int:
        return len(self.offsets) - 1

    def __getitem__(self, frame: int) -> np.ndarray:
        """A copy of the frame's cloud, RAM of its own as the keyframe store accounts it, in downsample's memory
        layout (column-major), so that products with it round as they did on the cloud downsampled here."""
        return np.asfortranarray(self.points[self.offsets[frame] : self.offsets[frame + 1]])


class ComputedClouds(NamedTuple):
    """io.cache.Computed of the frame clouds: a FrameClouds as `values` (clouds of varying size, not one array)."""

    values: FrameClouds
    cached: bool
    ms: np.ndarray


def cloud_key(sequence: ScanSequence, voxel_size: float, cache: CacheDir | None = None) -> str:
    """Cache key of a sequence's frame clouds: its scans' identity, the voxel size, CLOUD_CODE's fingerprint and
    library versions; `cache` memoises the files' digests."""
    return cache_key(
        "frame-clouds",
        sequence_inputs(sequence, (), cache),
        {"voxel_size": float(voxel_size)},
        code_fingerprint(CLOUD_CODE),
        CLOUD_LIBRARIES,
    )


def load_frame_clouds(sequence: ScanSequence, voxel_size: float, cache: CacheDir, key: str) -> ComputedClouds | None:
    """The cached clouds of every frame downsampled at `voxel_size` (a FrameClouds as `values`; entries
    `frame-cloud-offsets-<key>` and `frame-clouds-<key>`, checked to fit each other and the sequence) with the
    time (ms) downsampling each took when computed, or None when any part is absent or bad."""
    offsets_name, points_name = f"frame-cloud-offsets-{key}", f"frame-clouds-{key}"
    offsets = cache.load(offsets_name, _offsets_check(len(sequence)))
    if offsets is None:
        return None
    ms = cache.load_times(points_name, len(sequence))
    if ms is None:
        return None
    points = cache.load(points_name, _points_check(int(offsets[-1])), mapped=True)
    return None if points is None else ComputedClouds(FrameClouds(points, offsets, float(voxel_size)), True, ms)


def save_frame_clouds(
    clouds: Sequence[np.ndarray], ms: np.ndarray, voxel_size: float, cache: CacheDir | None, key: str
) -> ComputedClouds:
    """Every frame's freshly downsampled cloud (`clouds`, in frame order; computed while the front end reads the
    scans: pipeline.read_ahead) as one FrameClouds, stored in `cache` (None: not stored) with the time (ms)
    downsampling each took."""
    offsets = np.concatenate([[0], np.cumsum([len(c) for c in clouds])]).astype(np.int64)
    points = np.ascontiguousarray(np.concatenate(clouds))  # row-major: a frame's cloud is one block of the file
    if cache is not None:
        points_name = f"frame-clouds-{key}"
        cache.save_times(points_name, ms)
        if cache.save(points_name, points) is not None:
            cache.save(f"frame-cloud-offsets-{key}", offsets)  # written last: an entry without it is recomputed
    return ComputedClouds(FrameClouds(points, offsets, float(voxel_size)), False, ms)


def _offsets_check(frames: int) -> Callable[[np.ndarray], np.ndarray]:
    def check(offsets: np.ndarray) -> np.ndarray:
        if offsets.dtype != np.int64 or offsets.shape != (frames + 1,):
            raise ValueError(f"offsets {offsets.dtype.str} {offsets.shape}, expected int64 ({frames + 1},)")
        if offsets[0] != 0 or (np.diff(offsets) < 0).any():
            raise ValueError("offsets do not start at 0 and increase")
        return offsets

    return check


def _points_check(count: int) -> Callable[[np.ndarray], np.ndarray]:
    def check(points: np.ndarray) -> np.ndarray:
        if points.dtype != np.float32 or points.shape != (count, 3) or not points.flags.c_contiguous:
            raise ValueError(f"points {points.dtype.str} {points.shape}, expected float32 ({count}, 3) in C order")
        if not np.isfinite(points).all():
            raise ValueError("NaN or infinite values")
        return points

    return check
