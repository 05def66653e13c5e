"""A ground-truth pose file (`--gt`, KITTI or TUM, LiDAR frame) attached to any sequence: one pose a scan,
or, for a TUM file with another count, the pose nearest in time to each scan."""

from __future__ import annotations

import os

import numpy as np

from msa_slam.datasets.sequences import ScanSequence
from msa_slam.errors import InputError
from msa_slam.io.poses import read_poses


def attach_ground_truth(sequence: ScanSequence, path: str | os.PathLike, fmt: str = "auto") -> ScanSequence:
    """`sequence` with the poses of `path` as its ground truth; a time-matched pose must lie within half a
    scan period of its scan."""
    poses, times = read_poses(path, fmt)
    if len(poses) == len(sequence):
        sequence.gt_poses = poses
        return sequence
    if times is None:
        raise InputError(f"{path}: {len(poses)} poses but {sequence.path} has {len(sequence)} scans; a KITTI pose "
                         "file needs one pose a scan (a TUM file is matched to the scans by time)")
    scans = sequence.times
    order = np.argsort(times)
    times, poses = times[order], poses[order]
    right = np.clip(np.searchsorted(times, scans), 1, len(times) - 1) if len(times) > 1 else np.zeros(len(scans), int)
    left = np.maximum(right - 1, 0)
    nearest = np.where(np.abs(times[left] - scans) <= np.abs(times[right] - scans), left, right)
    gap = np.abs(times[nearest] - scans)
    tolerance = 0.5 * float(np.median(np.diff(scans))) if len(scans) > 1 else np.inf
    bad = np.flatnonzero(gap > tolerance)
    if len(bad):
        k = int(bad[0])
        raise InputError(f"{path}: no pose within {tolerance:.3g} s of scan {k} (time {scans[k]:.6f} s; nearest "
                         f"pose at {times[nearest[k]]:.6f} s); the pose times must be the scans' clock")
    sequence.gt_poses = poses[nearest]
    return sequence
