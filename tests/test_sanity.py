"""Plausibility warnings of the front end: degenerate odometry and ground-truth jumps are named,
while real trajectories (KITTI ground truth, KISS-ICP on a simulated street) pass without a warning."""

from __future__ import annotations

import logging
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msa_slam.evaluation.sanity import frontend_warnings, implausible_steps
from msa_slam.odometry import KissOdometry
from msa_slam.sim import load_trajectory


@pytest.fixture(scope="module")
def kitti():
    """The first 300 ground-truth poses of KITTI-05 (10 Hz) and their times."""
    trajectory = load_trajectory("kitti-05")
    return trajectory.poses[:300].copy(), trajectory.times[:300].copy()


def _drifted(gt: np.ndarray, yaw: float = 1e-3) -> np.ndarray:
    """An odometry estimate: every step of `gt` followed by a small yaw error."""
    bias = np.eye(4)
    bias[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    out = [np.eye(4)]
    for step in np.linalg.inv(gt[:-1]) @ gt[1:]:
        out.append(out[-1] @ step @ bias)
    return np.stack(out)


def test_real_trajectories_give_no_warning(kitti):
    gt, times = kitti
    assert frontend_warnings(gt, _drifted(gt), times) == []
    assert frontend_warnings(None, _drifted(gt), times) == []


def test_ground_truth_teleport_is_named(kitti):
    gt, times = kitti
    jumped = gt.copy()
    jumped[150:, 0, 3] += 1000.0  # a 1 km teleport
    warnings = frontend_warnings(jumped, _drifted(gt), times)
    assert len(warnings) == 1
    assert warnings[0].startswith("ground truth: 1 implausible step(s); the largest, frames 149 -> 150: 100")


def test_jump_beyond_the_median_step_without_times(kitti):
    gt, _ = kitti
    jumped = gt.copy()
    jumped[200:, 1, 3] += 30.0  # 30 m in one frame: plausible per "second" of frame-index times, not per step
    frames = np.arange(len(gt), dtype=np.float64)
    assert implausible_steps(gt, frames, "ground truth") == []
    assert "frames 199 -> 200" in implausible_steps(jumped, frames, "ground truth")[0]


def test_odometry_spin_is_implausible(kitti):
    gt, times = kitti
    odometry = _drifted(gt)
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("z", 60, degrees=True).as_matrix()  # 60 deg in 0.1 s
    odometry[100:] = odometry[99] @ turn @ np.linalg.inv(odometry[99]) @ odometry[100:]
    warnings = frontend_warnings(gt, odometry, times)
    assert len(warnings) == 1 and warnings[0].startswith("odometry: 1 implausible step(s); the largest, frames 99")
    assert re.search(r"60\.\d deg in 0\.1\d* s", warnings[0])


def test_stalled_odometry_is_named(kitti):
    gt, times = kitti
    standing = np.tile(np.eye(4), (len(gt), 1, 1))
    warnings = frontend_warnings(gt, standing, times)
    assert len(warnings) == 2
    assert warnings[0].startswith("odometry: stalled start: it moves 0.00 m over the first 20 steps")
    assert warnings[1].startswith("odometry: (near) zero motion on 299 of the 299 steps")
    late = np.concatenate([np.tile(np.eye(4), (99, 1, 1)), _drifted(gt[99:])])  # locks on at frame 99
    warnings = frontend_warnings(gt, late, times)
    assert len(warnings) == 2 and "stalled start" in warnings[0] and "on 99 of the 299 steps" in warnings[1]


def _ground_plane_scan(pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """What a LiDAR 1.7 m above an endless flat ground sees: a disc of ground points, nothing else."""
    radius = 40.0 * np.sqrt(rng.uniform(0.01, 1.0, 3000))
    angle = rng.uniform(0.0, 2 * np.pi, 3000)
    world = np.column_stack(
        [pose[0, 3] + radius * np.cos(angle), pose[1, 3] + radius * np.sin(angle), np.full(3000, -1.7)]
    )
    return (world - pose[:3, 3]) @ pose[:3, :3]


def test_kiss_icp_in_a_ground_plane_world_is_flagged():
    # A flat world gives ICP nothing to fix the motion along the ground: the odometry stays at
    # the origin (ATE 48.7 m in the issue) and the warnings say so.
    rng = np.random.default_rng(0)
    n = 25
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 0, 3] = 1.5 * np.arange(n)
    times = 0.1 * np.arange(n)
    odometry = KissOdometry(max_range=50.0)
    poses = np.stack([odometry.register(_ground_plane_scan(pose, rng)) for pose in gt])
    assert np.linalg.norm(poses[-1, :3, 3]) < 0.2 * gt[-1, 0, 3]  # the degenerate result the warnings are for
    warnings = frontend_warnings(gt, poses, times)
    assert any("stalled start" in w for w in warnings)
    assert any(re.search(rf"zero motion on \d+ of the {n - 1} steps", w) for w in warnings)


def test_kiss_icp_logs_frames_it_could_not_register(caplog):
    rng = np.random.default_rng(1)
    near = rng.normal(size=(2000, 3)) * 10.0
    odometry = KissOdometry(max_range=50.0)
    with caplog.at_level(logging.WARNING, logger="msa_slam.odometry.kiss"):
        odometry.register(near)
        odometry.register(near + 500.0)  # every point beyond max_range
        odometry.register(near)
    assert odometry.unregistered_frames == [1]
    assert [r.getMessage()[:60] for r in caplog.records] == [
        "KISS-ICP frame 1: none of its 2000 points lies within 0-50 m"
    ]


def test_camera_frame_ground_truth_is_named(kitti):
    """KITTI's poses/NN.txt are cam0 poses (z forward); given as LiDAR-frame ground truth every error turns."""
    gt, times = kitti
    velo_to_cam = np.eye(4)
    velo_to_cam[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]  # KITTI's Tr, up to its small offsets
    cam = velo_to_cam @ gt @ np.linalg.inv(velo_to_cam)
    warnings = frontend_warnings(cam, _drifted(gt), times)
    assert len(warnings) == 1
    assert re.fullmatch(
        r"ground truth: the sensor moves along its z axis on (\d+) of (\d+) moving steps, as a "
        r"camera does; .*calib\.txt's Tr.*",
        warnings[0],
    )
    along, moving = map(int, re.findall(r"\d+", warnings[0])[:2])
    assert along > 0.9 * moving and moving > 250
