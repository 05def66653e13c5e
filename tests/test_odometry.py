"""KISS-ICP odometry on real KITTI scans (Geiger et al., CVPR 2012), poses from files, the odometry cache."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from helpers.poses import pose_error
from helpers.scans import scan_points
from scipy.spatial.transform import Rotation

from msa_slam.datasets import folder_sequence
from msa_slam.errors import InputError
from msa_slam.io.poses import write_poses
from msa_slam.odometry import KissOdometry, OdometryCache, PosesFromFile, sequence_odometry
from msa_slam.odometry.kiss import RANGE_CHECK_POINTS
from msa_slam.registration import Verifier


def test_kiss_icp_agrees_with_gicp_on_real_scans():
    # GT lines 1 and 6 disagree with both registrations by ~0.7 m (see tests/test_registration.py), so the
    # reference here is small_gicp's estimate of the same pair: two independent registrations must agree.
    odometry = KissOdometry()
    first = odometry.register(scan_points(0))
    second = odometry.register(scan_points(5))
    np.testing.assert_allclose(first, np.eye(4), atol=1e-12)
    gicp = Verifier().verify(scan_points(0), scan_points(5)).T_target_source
    trans, rot = pose_error(np.linalg.inv(first) @ second, gicp)
    assert np.linalg.norm(second[:3, 3]) > 3.0
    assert trans < 0.15 and rot < 0.1


def test_kiss_icp_recovers_known_motion_of_a_real_scan():
    cloud = scan_points(0).astype(np.float64)
    step = np.eye(4)
    step[:3, :3] = Rotation.from_euler("z", 1.5, degrees=True).as_matrix()
    step[:3, 3] = [0.8, 0.05, 0.0]
    odometry = KissOdometry(max_range=60.0)
    truth = np.eye(4)
    for k in range(4):
        sensor_points = (cloud[k % 2 :: 2] - truth[:3, 3]) @ truth[:3, :3]  # world points seen from `truth`
        pose = odometry.register(sensor_points)
        trans, rot = pose_error(pose, truth)
        assert trans < 0.05 and rot < 0.1, f"frame {k}: {trans:.3f} m, {rot:.3f} deg"
        truth = truth @ step


def test_kiss_config_and_bad_parameters():
    odometry = KissOdometry(max_range=50.0)
    assert odometry.config["data"]["max_range"] == 50.0
    assert odometry.config["mapping"]["voxel_size"] == 0.5
    assert odometry.config["data"]["deskew"] is False
    with pytest.raises(InputError, match="min_range"):
        KissOdometry(max_range=5.0, min_range=10.0)
    with pytest.raises(InputError, match="odometry frame 0"):
        odometry.register(np.zeros((0, 3)))


def test_poses_from_file(tmp_path):
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 1.0, 2.5]
    write_poses(tmp_path / "odom.txt", poses)
    odometry = PosesFromFile(tmp_path / "odom.txt")
    assert len(odometry) == 3
    got = np.stack([odometry.register(None) for _ in range(3)])
    np.testing.assert_allclose(got, poses, atol=1e-9)
    with pytest.raises(InputError, match="has 3 poses but frame 3"):
        odometry.register(None)
    with pytest.raises(InputError, match="not found"):
        PosesFromFile(tmp_path / "missing.txt")


def test_pose_file_odometry_follows_the_scan_selection(tmp_path):
    # --odometry FILE with --first/--jump/-n: the file holds one pose a scan of the recording, like --gt
    from msa_slam.odometry.choice import make_odometry
    from msa_slam.pipeline.config import make_config

    poses = np.tile(np.eye(4), (10, 1, 1))
    poses[:, 0, 3] = np.arange(10.0)
    write_poses(tmp_path / "odom.txt", poses)
    selection = {"first": 2, "jump": 3, "frames": 3}
    config = make_config(dataset="sim:test", odometry=str(tmp_path / "odom.txt"), source=selection)
    odometry = make_odometry(config, 3)
    assert [odometry.register()[0, 3] for _ in range(3)] == [2.0, 5.0, 8.0]
    write_poses(tmp_path / "part.txt", poses[[2, 5, 8]])  # one pose a scan read: taken as it is
    part = make_odometry(make_config(dataset="sim:test", odometry=str(tmp_path / "part.txt"), source=selection), 3)
    assert [part.register()[0, 3] for _ in range(3)] == [2.0, 5.0, 8.0]
    with pytest.raises(InputError, match=r"odom.txt: 10 poses but the run reads 4 scans \(scans 2, 5, \.\.\. 11"):
        make_odometry(
            make_config(dataset="sim:test", odometry=str(tmp_path / "odom.txt"), source={**selection, "frames": 4}), 4
        )


class _CountingOdometry:
    """Stand-in odometry: pose i translates i metres; counts calls so the cache can be observed."""

    def __init__(self, tag: str = "a") -> None:
        self.config = {"method": "counting", "tag": tag}
        self.calls = 0

    def register(self, points, timestamps=None, time=None):
        pose = np.eye(4)
        pose[0, 3] = self.calls
        self.calls += 1
        return pose


def _scan_folder(path, n: int = 4):
    """A folder of n tiny .bin scans (what the odometry cache keys on)."""
    path.mkdir(parents=True)
    for k in range(n):
        np.full((5, 4), k, dtype=np.float32).tofile(path / f"{k:06d}.bin")
    return folder_sequence(path)


def test_sequence_odometry_is_cached_by_scans_and_config(tmp_path, caplog):
    seq = _scan_folder(tmp_path / "seq")
    cache = OdometryCache(tmp_path / "cache")
    first = _CountingOdometry()
    poses, cached, ms = sequence_odometry(seq, first, cache, quiet=True)
    assert first.calls == 4 and poses[3, 0, 3] == 3.0 and not cached and ms.shape == (4,) and (ms >= 0).all()
    again = _CountingOdometry()
    poses_again, cached, ms_again = sequence_odometry(seq, again, cache, quiet=True)
    np.testing.assert_array_equal(poses_again, poses)
    assert again.calls == 0 and cached
    np.testing.assert_array_equal(ms_again, ms)  # a replay counts the time computing took, recorded with the entry
    other_config = _CountingOdometry("b")
    sequence_odometry(seq, other_config, cache, quiet=True)
    assert other_config.calls == 4
    other_scans = _CountingOdometry()
    sequence_odometry(_scan_folder(tmp_path / "seq2", n=3), other_scans, cache, quiet=True)
    assert other_scans.calls == 3
    names = sorted(p.name.split("-")[0] for p in (tmp_path / "cache").iterdir())
    # the scans' digests, the poses' compute times (ms-odometry-KEY), poses, unregistered frames; no temp files left
    assert names == ["input"] + ["ms"] * 3 + ["odometry"] * 3 + ["unregistered"] * 3
    assert {p.suffix for p in (tmp_path / "cache").iterdir()} == {".json", ".npy"}
    # A corrupt cache entry is recomputed, not trusted, with a warning naming it.
    key = OdometryCache.key(seq, first.config)
    cache.path(key).write_bytes(b"garbage")
    recomputed = _CountingOdometry()
    _, cached, _ = sequence_odometry(seq, recomputed, cache, quiet=True)
    assert recomputed.calls == 4 and not cached
    assert str(cache.path(key)) in caplog.text


def test_a_cached_run_knows_the_frames_kiss_icp_could_not_register(tmp_path):
    """Frame 1 lies beyond max_range: the fresh run and the run from the cache both list it and say so in one
    line for the report; a cache entry without that list (an older msa-slam's) is recomputed."""
    rng = np.random.default_rng(1)
    near = np.hstack([rng.normal(size=(2000, 3)) * 10.0, np.zeros((2000, 1))]).astype(np.float32)
    folder = tmp_path / "seq"
    folder.mkdir()
    for k, scan in enumerate([near, near + np.float32(500.0), near]):
        scan.tofile(folder / f"{k:06d}.bin")
    cache = OdometryCache(tmp_path / "cache")
    fresh = KissOdometry(max_range=50.0)
    poses, cached, _ = sequence_odometry(folder_sequence(folder), fresh, cache, quiet=True)
    assert not cached and fresh.unregistered_frames == [1]
    replayed = KissOdometry(max_range=50.0)
    again, cached, _ = sequence_odometry(folder_sequence(folder), replayed, cache, quiet=True)
    assert cached and replayed.unregistered_frames == [1]
    np.testing.assert_array_equal(again, poses)
    assert replayed.unregistered_warning(3) == [
        "odometry: KISS-ICP could not register 1 of 3 frames (frame 1): fewer than 3 of their points lie within "
        "0-50 m, so their poses were extrapolated at constant velocity"
    ]
    assert KissOdometry().unregistered_warning(3) == []
    key = OdometryCache.key(folder_sequence(folder), fresh.config)
    cache.store.path(f"unregistered-{key}").unlink()
    legacy = KissOdometry(max_range=50.0)
    _, cached, _ = sequence_odometry(folder_sequence(folder), legacy, cache, quiet=True)
    assert not cached and legacy.unregistered_frames == [1]
    cache.store.path(f"ms-odometry-{key}").unlink()  # an entry without the time it took is recomputed too
    _, cached, _ = sequence_odometry(folder_sequence(folder), KissOdometry(max_range=50.0), cache, quiet=True)
    assert not cached


def test_points_in_range_past_a_scans_first_ones_count(caplog):
    """A scan's points in range are counted in its first RANGE_CHECK_POINTS first (they nearly always hold
    enough); when they do not, the rest count too: exactly, for the log."""
    scene = np.random.default_rng(1).normal(size=(2000, 3)) * 10.0
    far = np.random.default_rng(2).normal(size=(RANGE_CHECK_POINTS, 3)) + 500.0  # beyond max_range
    odometry = KissOdometry(max_range=50.0)
    with caplog.at_level(logging.WARNING, logger="msa_slam.odometry.kiss"):
        poses = [odometry.register(scene - [0.5 * k, 0.0, 0.0]) for k in range(3)]
        poses.append(odometry.register(np.vstack([far, scene[:2]])))  # 2 in range, past the first ones
        poses.append(odometry.register(np.vstack([far, scene - [2.0, 0.0, 0.0]])))  # in range past them only
    assert odometry.unregistered_frames == [3]
    assert [r.getMessage() for r in caplog.records] == [
        f"KISS-ICP frame 3: only 2 of its {RANGE_CHECK_POINTS + 2} points lie within 0-50 m (registration needs 3), "
        "so it was not registered (pose extrapolated at constant velocity)"
    ]
    np.testing.assert_allclose(poses[4][:3, 3], [2.0, 0.0, 0.0], atol=0.05)  # registered: it moved on
