"""Pose and point conventions shared by every stage.

Poses are (4, 4) float64 world-from-sensor SE(3) matrices in the LiDAR frame; sequences are (N, 4, 4).
Points are (P, 3) float32/float64 in the sensor frame.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from msa_slam.errors import InputError

if TYPE_CHECKING:
    from msa_slam.datasets import ScanSequence

ROTATION_TOLERANCE = 1e-4


def validate_pose(pose: np.ndarray, where: str = "pose") -> np.ndarray:
    """Return `pose` as a (4, 4) float64 array, or raise InputError naming `where`."""
    arr = np.asarray(pose, dtype=np.float64)
    if arr.shape != (4, 4):
        raise InputError(f"{where}: expected a 4x4 pose, got shape {arr.shape}")
    fault = pose_fault(arr[None])
    if fault is not None:  # "frame 3 pose has NaN ...", not validate_poses' "frame 3 pose: frame 0 has NaN ..."
        raise InputError(f"{where} {fault[1]}")
    return arr


def validate_poses(poses: np.ndarray, where: str = "poses") -> np.ndarray:
    """Check an (N, 4, 4) pose stack is finite and rigid; the error names the first bad frame."""
    arr = np.asarray(poses, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise InputError(f"{where}: expected poses of shape (N, 4, 4), got {arr.shape}")
    fault = pose_fault(arr)
    if fault is not None:
        raise InputError(f"{where}: frame {fault[0]} {fault[1]}")
    return arr


def pose_fault(poses: np.ndarray, tolerance: float = ROTATION_TOLERANCE) -> tuple[int, str] | None:
    """(index, what is wrong) of the first pose of an (N, 4, 4) stack that is not finite (checked first), else
    of the first that is not rigid (rotation off orthonormal or det 1 by more than `tolerance`); None when all
    are fine. Apart from validate_poses so that a pose file's reader can name the line instead of the frame."""
    finite = np.isfinite(poses).all(axis=(1, 2))
    if not finite.all():
        return int(np.argmin(finite)), "has NaN or infinite values"
    rot = poses[:, :3, :3]
    ortho_err = np.abs(rot @ rot.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot)
    bad = (ortho_err > tolerance) | (np.abs(det - 1.0) > tolerance)
    bottom_bad = np.abs(poses[:, 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=1) > 1e-9
    bad |= bottom_bad
    if not bad.any():
        return None
    k = int(np.argmax(bad))
    last_row = f", last row {poses[k, 3].tolist()}" if bottom_bad[k] else ""  # named only when it is the fault
    return k, f"is not a rigid transform (|R R^T - I| = {ortho_err[k]:.2e}, det R = {det[k]:.6f}{last_row})"


def as_points(points: np.ndarray, where: str = "points") -> np.ndarray:
    """Return `points` as a finite (P, 3) float64 array with P > 0, or raise InputError naming `where`.

    Extra columns (e.g. KITTI reflectance) are dropped; non-finite rows are an error, not silently removed.
    """
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] < 3:
        raise InputError(f"{where}: expected points of shape (P, 3), got {arr.shape}")
    arr = np.ascontiguousarray(arr[:, :3], dtype=np.float64)
    if len(arr) == 0:
        raise InputError(f"{where}: point cloud is empty")
    if not np.isfinite(arr).all():
        raise InputError(f"{where}: point cloud has NaN or infinite coordinates")
    return arr


def translations(poses: np.ndarray) -> np.ndarray:
    """(N, 3) translations of an (N, 4, 4) pose stack."""
    return np.asarray(poses)[:, :3, 3]


@dataclass(frozen=True)
class LoopClosure:
    """A descriptor match between keyframes `query` (newer) and `match` (older), in frame indices, and the
    outcome of its verification: `T_match_query` maps query-frame points into the match frame, with
    `covariance` (6x6, rotation then translation) for the loop factor; `rejected` names the gate a
    registered candidate failed ("" when accepted or not registered); `travelled_m` is the odometry path
    length between the two keyframes."""

    query: int
    match: int
    similarity: float
    gt_distance: float
    verified: bool = False
    accepted: bool = False
    residual: float = float("nan")
    T_match_query: np.ndarray | None = None
    covariance: np.ndarray | None = None
    rejected: str = ""
    travelled_m: float = float("nan")


@dataclass
class FrameSource:
    """A stream of frames with known length and (when known) ground truth (what the online pipeline reads);
    `sequence`: the scans the frames are read from, as selected (--first/--jump/-n): they key cached odometry
    as in the batch pipeline (None for scans made in memory); `length` is needed only without ground truth;
    `point_times`: whether the frames carry per-point times (`timestamps`, which
    deskewing needs): True makes KISS-ICP deskew unless asked not to, False makes it not deskew (an asked deskew
    is dropped with a warning); None (not known): deskew only when asked, and KISS-ICP then refuses a first frame
    without them (odometry.choice.make_odometry). `live`: frames that come once, as from a sensor (nothing to
    replay bit for bit), so the online pipeline runs KISS-ICP on every core by default
    (pipeline.live.with_odometry_threads). `identity`: what determines frames made in memory (a live: source's
    simulation key and laps), which keys their cached odometry as a sequence's scans key theirs. `producer`:
    a picklable callable that makes the same frames in another process (a live: source's simulation, run beside
    the odometry: pipeline.live.arriving), or None."""

    name: str
    gt_poses: np.ndarray | None
    frames: Callable[[], Iterator[Any]]  # msa_slam.datasets.Frame objects, in time order
    sequence: ScanSequence | None = None
    length: int | None = None
    times_known: bool = True  # False: the frames' times are frame numbers (a recording without timestamps)
    point_times: bool | None = None
    live: bool = False
    identity: str | None = None
    producer: Callable[[], Iterable[Any]] | None = None

    def __len__(self) -> int:
        return len(self.gt_poses) if self.length is None else self.length
