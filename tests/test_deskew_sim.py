"""Deskew on the simulator's motion-distorted sweeps: the simulator and the odometry's deskew agree on every
convention (sweep direction, time origin, the column at the scan timestamp, sign, the sensor frame of the
points), and a short simulated distorted sequence drifts less with deskew (its default for these scans, which
carry per-point times) than with `-p odometry.deskew=false`."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from msa_slam.odometry import KissOdometry
from msa_slam.odometry.deskew import deskew, se3_log
from msa_slam.pipeline.config import apply_params, make_config
from msa_slam.pipeline.frontend import prepare_frontend
from msa_slam.sim.sensors import Lidar, LidarModel, SensorRealism
from msa_slam.sim.shapes import Material
from msa_slam.sim.world import World

# The sensor turns 40 deg/s while moving 12 m/s forward and 1 m/s sideways: a 10 Hz sweep turns 4 deg.
MOTION = np.array([1.2, 0.1, 0.0, 0.0, 0.0, np.radians(4.0)])  # (rho, phi) over one sweep (0.1 s)


def _twist(xi: np.ndarray) -> np.ndarray:
    x = np.zeros((4, 4))
    x[:3, :3] = [[0, -xi[5], xi[4]], [xi[5], 0, -xi[3]], [-xi[4], xi[3], 0]]
    x[:3, 3] = xi[:3]
    return x


def _room() -> World:
    """A closed 60 x 40 x 12 m box with a pillar off-centre, so no direction is symmetric."""
    mesh = trimesh.util.concatenate(
        [
            trimesh.creation.box(extents=[60.0, 40.0, 12.0]),
            trimesh.creation.box(
                extents=[2.0, 3.0, 10.0], transform=trimesh.transformations.translation_matrix([9.0, 6.0, 0.0])
            ),
        ]
    )
    faces = len(mesh.faces)
    return World(mesh, np.full(faces, 0.5, dtype=np.float32), np.full(faces, Material.SOLID, dtype=np.uint8))


def _pose_at(times: np.ndarray) -> np.ndarray:
    """Constant-twist motion whose pose at time 0 (the scan timestamp) is a yawed, shifted start."""
    start = np.eye(4)
    start[:3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    start[:3, 3] = [-5.0, 2.0, 0.0]
    return np.stack([start @ expm(t / 0.1 * _twist(MOTION)) for t in np.atleast_1d(times)])


@pytest.fixture(scope="module")
def sweep():
    model = LidarModel("test", tuple(np.linspace(10.0, -20.0, 16)), azimuth_steps=720, range_noise=0.0)
    points, times = Lidar(model, _room(), SensorRealism(motion_distortion=True)).sweep(
        _pose_at, 0.0, np.random.default_rng(0)
    )
    points = points[:, :3].astype(np.float64)
    # ground truth: each point through the pose of its firing time into the frame of the scan timestamp
    fired = _pose_at(times - model.sweep_period / 2)
    world = np.einsum("kij,kj->ki", fired[:, :3, :3], points) + fired[:, :3, 3]
    mid = _pose_at(np.array([0.0]))[0]
    return model, points, times, (world - mid[:3, 3]) @ mid[:3, :3]


def test_deskew_undoes_the_simulated_distortion_exactly(sweep):
    model, points, times, truth = sweep
    assert np.median(np.linalg.norm(points - truth, axis=1)) > 0.2  # the distortion is large
    rho, phi = MOTION[:3], MOTION[3:]
    np.testing.assert_allclose(deskew(points, times / model.sweep_period, rho, phi), truth, atol=1e-4)
    # any other convention leaves it distorted: the sweep reversed, or the opposite sign
    for fractions, sign in ((1.0 - times / model.sweep_period, 1.0), (times / model.sweep_period, -1.0)):
        wrong = deskew(points, fractions, sign * rho, sign * phi)
        assert np.median(np.linalg.norm(wrong - truth, axis=1)) > 0.2


def test_odometry_deskew_of_a_simulated_sweep(sweep):
    """The wrapper normalises the times by their span (as for any loader); the reference is then the middle
    of the first and last column, half a column (0.07 ms) before the scan timestamp."""
    model, points, times, truth = sweep
    motion = expm(_twist(MOTION))
    rho, phi = se3_log(motion)
    np.testing.assert_allclose(np.r_[rho, phi], MOTION, atol=1e-12)
    share = float(np.ptp(times)) / model.sweep_period
    corrected = KissOdometry._deskew(points, times, share, motion)
    reach = np.linalg.norm(points, axis=1).max()
    half_column = (np.linalg.norm(MOTION[:3]) + reach * MOTION[5]) / (2 * model.azimuth_steps)  # m a point moves
    assert np.abs(corrected - truth).max() < 1.01 * half_column


def _drift(deskew_on: bool, dataset: str, cache: str) -> float:
    """KISS-ICP's error over the whole prefix (the last frame's translation, first frames aligned), m."""
    config = apply_params(make_config(dataset=dataset, cache_dir=cache), [f"odometry.deskew={str(deskew_on).lower()}"])
    frontend = prepare_frontend(config)
    gt = np.linalg.inv(frontend.gt_poses[0]) @ frontend.gt_poses
    est = frontend.odometry
    return float(np.linalg.norm((np.linalg.inv(gt[-1]) @ est[-1])[:3, 3]))


def test_simulated_distorted_sequence_drifts_less_with_deskew(tmp_path):
    # KITTI-07's first 40 frames (kitti preset: motion distortion and every other imperfection) turn a corner
    # at ~22 deg/s. Measured over seeds 0-2 and 360/720 azimuth steps (SIM_VERSION 12): deskew on ends 2.4-3.9x
    # closer. The mean frame-to-frame error does not separate them (on / off 0.86-1.08 over those six runs; on
    # SIM_VERSION 11 seed 2 at 360 steps gave 1.03), so only the end is asserted.
    dataset, cache = "sim:kitti-07,end=40,azimuth_steps=360", str(tmp_path / "cache")
    off_final = _drift(False, dataset, cache)
    on_final = _drift(True, dataset, cache)
    assert off_final > 0.1  # the distortion matters here
    assert on_final < 0.7 * off_final
