"""A ground-truth pose file (`--gt`, KITTI or TUM, LiDAR frame) attached to any sequence: a KITTI file one pose
a scan, a TUM file the pose nearest in time to each scan (one pose a scan, in order, when the scans have no
timestamps of their own: its times then become theirs)."""

from __future__ import annotations

import os

import numpy as np

from msa_slam.datasets.sequences import ScanSequence
from msa_slam.errors import InputError
from msa_slam.io.poses import read_poses


def nearest_in_time(pose_times: np.ndarray, scan_times: np.ndarray, path: str | os.PathLike) -> np.ndarray:
    """Index of the pose nearest in time to each scan; `pose_times` increase strictly (as read_poses checks).
    A pose further than half the median scan period from its scan means the file does not cover the scans or
    runs on another clock: an InputError names `path` and the first such scan, instead of a wrong ground truth."""
    right = np.searchsorted(pose_times, scan_times)
    right = np.clip(right, 1, len(pose_times) - 1) if len(pose_times) > 1 else np.zeros(len(scan_times), int)
    left = np.maximum(right - 1, 0)
    nearest = np.where(np.abs(pose_times[left] - scan_times) <= np.abs(pose_times[right] - scan_times), left, right)
    gap = np.abs(pose_times[nearest] - scan_times)
    tolerance = 0.5 * float(np.median(np.diff(scan_times))) if len(scan_times) > 1 else np.inf
    bad = np.flatnonzero(gap > tolerance)
    if len(bad):
        k = int(bad[0])
        raise InputError(
            f"{path}: no pose within {tolerance:.3g} s of scan {k} (time {scan_times[k]:.6f} s; "
            f"nearest pose at {pose_times[nearest[k]]:.6f} s); the pose times must be the scans' clock"
        )
    return nearest


def attach_ground_truth(sequence: ScanSequence, path: str | os.PathLike, fmt: str = "auto") -> ScanSequence:
    """`sequence` with the poses of `path` as its ground truth; a TUM pose must lie within half a scan period
    of its scan (see nearest_in_time) whenever the scans have timestamps, whatever the count."""
    poses, times = read_poses(path, fmt)
    if times is not None and sequence.times_known:
        sequence.gt_poses = poses[nearest_in_time(times, sequence.times, path)]
        return sequence
    if len(poses) != len(sequence) and times is None:
        raise InputError(
            f"{path}: {len(poses)} poses but {sequence.path} has {len(sequence)} scans; a KITTI pose "
            "file needs one pose a scan (a TUM file is matched to the scans by time)"
        )
    if len(poses) != len(sequence):
        raise InputError(
            f"{path}: {len(poses)} poses but {sequence.path} has {len(sequence)} scans, which have no "
            "timestamps to match the TUM times to; give one pose a scan"
        )
    sequence.gt_poses = poses
    if times is not None:
        sequence.times, sequence.times_known = times, True
    return sequence
