"""Loop verification on real KITTI scans (Geiger et al., CVPR 2012) and on constructed failures.

Measured on the three shared scans of sequence 00: the registrations 0->5, 5->15 and 0->15 agree with each
other to 1.6 cm / 0.02 deg, but differ from the relative poses of GT lines 1, 6, 16 by 0.74 m / 0.61 deg
(0->5) and 1.2 m / 1.6 deg (0->15); the GT pose aligns the scans worse than the registration does
(inliers within 0.3 m: 36 % vs 68 %), so the GT tolerance below is the measured disagreement, and the
tight checks are chain consistency and a known transform applied to a real scan.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_path
from helpers.poses import pose_error
from helpers.scans import scan_points
from scipy.spatial.transform import Rotation

from msa_slam.errors import InputError
from msa_slam.registration import KeyframeCloudStore, Verifier, VerifierConfig, downsample


def _gt_lidar_relative(a: int, b: int) -> np.ndarray:
    """T_a_b from KITTI cam0 GT converted to the Velodyne frame: inv(Tr) P Tr."""
    rows = np.loadtxt(shared_path("data", "kitti_gt", "00.txt")).reshape(-1, 3, 4)
    calib = [
        line.split()
        for line in shared_path("data", "kitti_gt", "calib.txt").read_text().splitlines()
        if line.startswith("00 ")
    ][0]
    tr = np.eye(4)
    tr[:3, :4] = np.array(calib[1:], dtype=float).reshape(3, 4)

    def lidar(i: int) -> np.ndarray:
        pose = np.eye(4)
        pose[:3, :4] = rows[i]
        return np.linalg.inv(tr) @ pose @ tr

    return np.linalg.inv(lidar(a)) @ lidar(b)


@pytest.fixture(scope="module")
def scans() -> dict[int, np.ndarray]:
    return {i: scan_points(i) for i in (0, 5, 15)}


def test_real_pair_is_accepted_near_ground_truth(scans):
    result = Verifier().verify(scans[0], scans[5])
    assert result.accepted
    assert result.residual < 0.2
    assert result.inlier_fraction > 0.9 and result.target_fraction > 0.85 and result.rejected == ""
    sigmas = np.sqrt(np.diag(result.covariance))  # from the GICP Hessian: a well-constrained street scene
    assert np.all(sigmas > 0) and sigmas[3:].max() < 0.05 and sigmas[:3].max() < 0.005
    trans, rot = pose_error(result.T_target_source, _gt_lidar_relative(0, 5))
    assert trans < 0.8 and rot < 0.7  # the measured scan/GT disagreement (see module docstring)


def test_real_registrations_are_mutually_consistent(scans):
    verifier = Verifier()
    t05 = verifier.verify(scans[0], scans[5])
    t015 = verifier.verify(scans[0], scans[15])
    t515 = verifier.verify(scans[5], scans[15], initial_guess=_gt_lidar_relative(5, 15))
    assert t05.accepted and t015.accepted and t515.accepted
    trans, rot = pose_error(t05.T_target_source @ t515.T_target_source, t015.T_target_source)
    assert trans < 0.05 and rot < 0.1


def test_known_transform_of_a_real_scan_is_recovered(scans):
    cloud = scans[0].astype(np.float64)
    known = np.eye(4)
    known[:3, :3] = Rotation.from_euler("zyx", [8.0, 1.0, -0.5], degrees=True).as_matrix()
    known[:3, 3] = [2.0, -1.0, 0.2]
    source = (cloud[1::2] - known[:3, 3]) @ known[:3, :3]  # disjoint points, seen from the moved sensor
    result = Verifier().verify(cloud[::2], source)
    assert result.accepted
    trans, rot = pose_error(result.T_target_source, known)
    assert trans < 0.02 and rot < 0.05


def test_bad_initial_guess_is_rejected(scans):
    guess = np.eye(4)
    guess[:3, :3] = Rotation.from_euler("z", 150, degrees=True).as_matrix()
    guess[:3, 3] = [25.0, 10.0, 0.0]
    result = Verifier().verify(scans[0], scans[15], initial_guess=guess)
    assert not result.accepted
    assert result.residual > 0.3 or result.inlier_fraction < 0.5


def test_random_points_are_rejected(scans):
    target = scans[0].astype(np.float64)
    rng = np.random.default_rng(0)
    noise = rng.uniform(target.min(axis=0), target.max(axis=0), size=(20000, 3))
    result = Verifier().verify(target, noise)
    assert not result.accepted and result.rejected == "overlap"
    assert result.inlier_fraction < 0.2


def test_residual_gate_is_configurable(scans):
    strict = Verifier(VerifierConfig(max_residual=0.05)).verify(scans[0], scans[5])
    assert not strict.accepted and 0.05 < strict.residual < 0.3


@pytest.mark.parametrize("bad", [np.zeros((0, 3)), np.zeros((10, 2)), np.full((50, 3), np.nan)])
def test_bad_clouds_raise(bad):
    good = np.random.default_rng(1).normal(size=(500, 3))
    with pytest.raises(InputError, match="source cloud"):
        Verifier().verify(good, bad)


def test_bad_config_raises():
    with pytest.raises(InputError, match="max_residual"):
        VerifierConfig(max_residual=0.0)


def test_keyframe_store_downsamples_and_accounts_bytes():
    grid = np.stack(np.meshgrid(*[np.arange(0, 2, 0.1)] * 3), axis=-1).reshape(-1, 3)  # 20^3 points
    store = KeyframeCloudStore(voxel_size=0.5)
    stored = store.add(7, grid)
    assert stored.dtype == np.float32 and len(stored) == 4 * 4 * 4
    assert store.nbytes == 64 * 3 * 4 and len(store) == 1 and 7 in store
    np.testing.assert_array_equal(store[7], stored)
    assert len(downsample(grid, 1.0)) == 8
    with pytest.raises(InputError, match="keyframe 3"):
        store[3]
    with pytest.raises(InputError, match="keyframe 8"):
        store.add(8, np.zeros((0, 3)))
