"""Plausibility of the front end's trajectories: warnings, not errors, for results that would mislead.

A KISS-ICP run that never moves (a ground-plane-only world, scans of the wrong type), a ground-truth
file with a teleport or ground truth in another frame than the LiDAR's still produce an ATE; these checks say
why that number is not an odometry error.
Steps are judged against what a platform can do: MAX_SPEED_MPS and MAX_ROTATION_RATE_DPS given the
frame times (seconds; with frame indices as times the limits are per frame, so only gross jumps show),
and STEP_FACTOR times the median step, which catches a jump even without meaningful times.
"""

from __future__ import annotations

import numpy as np

from msa_slam.types import validate_poses

MAX_SPEED_MPS = 60.0  # 216 km/h: beyond cars, robots and hand-held rigs
MAX_ROTATION_RATE_DPS = 180.0  # half a turn a second
STEP_FACTOR = 10.0  # a step this many times the median step is a jump...
MIN_JUMP_M = 5.0  # ...when it is also at least this long (stationary data has a median step of ~0)
MOVING_STEP_M = 0.05  # a ground-truth step this long means the platform moves
STALLED_FRACTION = 0.25  # odometry moving less than this share of the ground truth's step is stalled: no
# working odometry underestimates motion by 75 %
MAX_STALLED_SHARE = 0.2  # warn when more than this share of the moving frames is stalled
REVERSED_COS = -0.5  # a ground-truth step more than 120 deg off the odometry's step, in the sensor frame...
REVERSED_SHARE = 0.5  # ...on more than this share of the steps where both move: ground truth turned ~180 deg
START_FRAMES = 20  # frames of the "stalled start" check
MIN_START_PATH_M = 1.0  # ground-truth path over START_FRAMES needed to judge a start


def _local_steps(poses: np.ndarray) -> np.ndarray:
    """Every frame-to-frame motion in the sensor frame of its first pose (independent of the world frame)."""
    return np.linalg.inv(poses[:-1]) @ poses[1:]


def _steps(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation (deg) of every frame-to-frame motion (independent of the world frame)."""
    relative = _local_steps(poses)
    cos = np.clip((np.trace(relative[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.linalg.norm(relative[:, :3, 3], axis=1), np.degrees(np.arccos(cos))


def implausible_steps(poses: np.ndarray, times: np.ndarray, what: str) -> list[str]:
    """Warnings for steps of `poses` faster than a platform moves or far beyond the median step."""
    poses = validate_poses(poses, what)
    if len(poses) < 2:
        return []
    dt = np.diff(np.asarray(times, dtype=np.float64))
    moves, turns = _steps(poses)
    speed, rate = moves / dt, turns / dt
    jump = (moves > STEP_FACTOR * np.median(moves)) & (moves >= MIN_JUMP_M)
    bad = np.flatnonzero((speed > MAX_SPEED_MPS) | (rate > MAX_ROTATION_RATE_DPS) | jump)
    if not len(bad):
        return []
    i = int(bad[np.argmax(moves[bad])])
    return [
        f"{what}: {len(bad)} implausible step(s); the largest, frames {i} -> {i + 1}: {moves[i]:.2f} m and "
        f"{turns[i]:.1f} deg in {dt[i]:.3g} s ({speed[i]:.1f} m/s, {rate[i]:.0f} deg/s; a platform moves at "
        f"most {MAX_SPEED_MPS:g} m/s and {MAX_ROTATION_RATE_DPS:g} deg/s; the median step is "
        f"{np.median(moves):.2f} m)"
    ]


def steps_along_z(poses: np.ndarray) -> tuple[np.ndarray, int]:
    """Indices k of the steps (pose k to k + 1, over 1 cm) whose motion, in the sensor frame, is mostly along z,
    and the number of such moving steps: a vehicle's LiDAR moves along x, a camera (KITTI's cam0) along z."""
    moving = np.flatnonzero(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) > 0.01)
    local = np.einsum("kji,kj->ki", poses[moving, :3, :3], poses[moving + 1, :3, 3] - poses[moving, :3, 3])
    return moving[np.abs(local[:, 2]) > 0.7 * np.linalg.norm(local, axis=1)], len(moving)


def camera_frame_poses(gt_poses: np.ndarray) -> list[str]:
    """A warning when the ground truth moves along the sensor's z axis on most steps: camera poses (KITTI's
    poses/NN.txt are cam0's) given where LiDAR-frame poses belong, which rotates every error."""
    along_z, moving = steps_along_z(validate_poses(gt_poses, "ground truth"))
    if moving == 0 or len(along_z) <= 0.5 * moving:
        return []
    return [
        f"ground truth: the sensor moves along its z axis on {len(along_z)} of {moving} moving steps, as a "
        "camera does; ground truth must be LiDAR-frame poses (x forward, z up): KITTI's cam0 poses need "
        "calib.txt's Tr (a KITTI layout folder with calib.txt converts them)"
    ]


def reversed_ground_truth(gt_poses: np.ndarray, odometry: np.ndarray) -> list[str]:
    """A warning when, in the sensor frame, the ground truth moves against the odometry on most steps: its frame
    is turned ~180 deg about z against the LiDAR's, which no alignment removes (the rotation ATE comes out near
    180 deg). MulRan's ground truth is the vehicle base's pose, turned into the Ouster's (mounted facing backwards)
    by the loader's calibration: poses that were the Ouster's already come out turned."""
    gt_steps = _local_steps(validate_poses(gt_poses, "ground truth"))[:, :3, 3]
    odom_steps = _local_steps(validate_poses(odometry, "odometry"))[:, :3, 3]
    gt_len, odom_len = np.linalg.norm(gt_steps, axis=1), np.linalg.norm(odom_steps, axis=1)
    moving = (gt_len > MOVING_STEP_M) & (odom_len > MOVING_STEP_M * STALLED_FRACTION)
    cos = np.einsum("ki,ki->k", gt_steps[moving], odom_steps[moving]) / (gt_len[moving] * odom_len[moving])
    reversed_steps = int((cos < REVERSED_COS).sum())
    if not moving.any() or reversed_steps <= REVERSED_SHARE * moving.sum():
        return []
    return [
        f"ground truth: in the sensor frame it moves against the odometry on {reversed_steps} of the "
        f"{int(moving.sum())} steps where both move: its frame is turned about 180 deg against the LiDAR's (the "
        "rotation ATE comes out near 180 deg). MulRan: global_pose.csv must hold the vehicle base's poses, as "
        "shipped; the loader turns them into the Ouster's with the base-to-Ouster calibration (a 179.7 deg "
        "yaw), so poses already in the Ouster frame come out turned"
    ]


def stalled_odometry(gt_poses: np.ndarray, odometry: np.ndarray) -> list[str]:
    """Warnings when the odometry stands (nearly) still while the ground truth moves: at the start, or on a
    large share of the frames (registration that does not lock on, or scans that cannot be registered)."""
    gt_moves, _ = _steps(validate_poses(gt_poses, "ground truth"))
    odom_moves, _ = _steps(validate_poses(odometry, "odometry"))
    warnings = []
    start_gt, start_odom = gt_moves[:START_FRAMES].sum(), odom_moves[:START_FRAMES].sum()
    if start_gt >= MIN_START_PATH_M and start_odom < STALLED_FRACTION * start_gt:
        warnings.append(
            f"odometry: stalled start: it moves {start_odom:.2f} m over the first "
            f"{min(START_FRAMES, len(gt_moves))} steps while the ground truth moves {start_gt:.1f} m "
            "(registration found nothing to lock on to?)"
        )
    moving = gt_moves >= MOVING_STEP_M
    stalled = moving & (odom_moves < STALLED_FRACTION * gt_moves)
    if moving.any() and stalled.sum() > MAX_STALLED_SHARE * moving.sum():
        warnings.append(
            f"odometry: (near) zero motion on {int(stalled.sum())} of the {int(moving.sum())} steps "
            f"where the ground truth moves (< {100 * STALLED_FRACTION:g} % of its step); its ATE "
            "measures a failed registration, not drift"
        )
    return warnings


def frontend_warnings(gt_poses: np.ndarray | None, odometry: np.ndarray, times: np.ndarray) -> list[str]:
    """Every plausibility warning of a front end: camera-frame, jumping or reversed ground truth, implausible or
    stalled odometry."""
    warnings = []
    if gt_poses is not None:
        warnings += camera_frame_poses(gt_poses) + implausible_steps(gt_poses, times, "ground truth")
    warnings += implausible_steps(odometry, times, "odometry")
    if gt_poses is not None:
        warnings += reversed_ground_truth(gt_poses, odometry) + stalled_odometry(gt_poses, odometry)
    return warnings
