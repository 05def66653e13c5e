"""Scan Context against the authors' vectors and on real KITTI scans (Geiger et al., CVPR 2012)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_path
from helpers.scans import load_scan

from msa_slam.descriptors.scan_context import ScanContext
from msa_slam.descriptors.voxel import voxel_downsample
from msa_slam.errors import InputError


@pytest.fixture(scope="module")
def parity():
    data = np.load(shared_path("parity", "scan_context_kitti00.npz"))
    offsets = data["offsets"]
    clouds = [data["points"][offsets[k] : offsets[k + 1]] for k in range(len(offsets) - 1)]
    return clouds, data["expected_sc"], data["expected_similarity"], list(data["names"])


def rotate_z(points: np.ndarray, degrees: float) -> np.ndarray:
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return points[:, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T


def test_binning_reproduces_reference_descriptors(parity):
    clouds, expected, _, _ = parity
    sc = ScanContext()
    got = np.stack([sc.bin(cloud) for cloud in clouds])
    assert got.shape == (9, 20, 60)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)


def test_similarity_matrix_matches_reference(parity):
    _, expected_sc, expected_sim, _ = parity
    sc = ScanContext()
    pairwise = np.array([[sc.similarity(a, b) for b in expected_sc] for a in expected_sc])
    batched = np.stack([sc.similarity_many(a, expected_sc) for a in expected_sc])
    np.testing.assert_allclose(pairwise, expected_sim, rtol=0, atol=1e-9)
    np.testing.assert_allclose(batched, expected_sim, rtol=0, atol=1e-9)


def test_voxel_centroids_reproduce_reference_cloud(parity):
    clouds, _, _, names = parity
    assert names[0] == "000000.bin@yaw0"
    ours = voxel_downsample(load_scan("000000"), 0.5)
    ref = clouds[0]
    assert ours.shape == ref.shape
    np.testing.assert_array_equal(ours[np.lexsort(ours.T)], ref[np.lexsort(ref.T)])


def test_voxel_centroids_match_sort_based_reference_with_many_voxels():
    """Tiny voxels force the hash table to grow many times; compare with np.unique grouping."""
    pts = np.random.default_rng(0).random((20_000, 3)) * 50.0
    ours = voxel_downsample(pts.astype(np.float32), 0.05)
    p64 = pts.astype(np.float32).astype(np.float64)
    keys = np.floor((p64 - p64.min(axis=0)) / 0.05).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse.ravel(), p64)
    ref = sums / counts[:, None]
    assert ours.shape == ref.shape
    np.testing.assert_allclose(ours[np.lexsort(ours.T)], ref[np.lexsort(ref.T)], rtol=0, atol=1e-12)


def test_full_pipeline_from_raw_scan_matches_reference(parity):
    _, expected, _, _ = parity
    np.testing.assert_allclose(ScanContext().compute(load_scan("000000")), expected[0], rtol=0, atol=1e-9)


def test_nearby_scan_more_similar_than_distant_one():
    sc = ScanContext()
    d0, d5, d15 = (sc.compute(load_scan(n)) for n in ("000000", "000005", "000015"))
    assert sc.similarity(d0, d5) > sc.similarity(d0, d15)


@pytest.mark.parametrize(("yaw", "floor"), [(30.0, 0.99), (90.0, 0.99), (300.0, 0.99), (137.0, 0.85), (250.0, 0.85)])
def test_yaw_rotated_copies_stay_near_one(yaw, floor):
    """Whole-sector yaws stay ~1; others lose a little to sector discretisation, still far above another place."""
    sc = ScanContext()
    scan = load_scan("000000")
    base, turned = sc.compute(scan), sc.compute(rotate_z(scan, yaw))
    sim, shift = sc.align(base, turned)
    assert sim > floor
    assert sim > sc.similarity(base, sc.compute(load_scan("000015"))) + 0.2
    assert abs((shift - yaw + 180.0) % 360.0 - 180.0) <= 6.0


def test_exact_column_roll_is_identical_up_to_yaw():
    rng = np.random.default_rng(3)
    a = rng.random((20, 60))
    sc = ScanContext()
    assert sc.similarity(a, np.roll(a, 17, axis=1)) == pytest.approx(1.0, abs=1e-12)
    assert sc.align(a, np.roll(a, 17, axis=1))[1] == pytest.approx(17 * 6.0)
    assert sc.similarity(a, np.roll(a, 17, axis=1)) == pytest.approx(sc.similarity(np.roll(a, 17, axis=1), a))


def test_zero_descriptor_scores_zero():
    sc = ScanContext()
    a = np.ones((20, 60))
    assert sc.similarity(np.zeros((20, 60)), a) == 0.0
    np.testing.assert_allclose(sc.similarity_many(a, np.stack([np.zeros((20, 60)), a])), [0.0, 1.0], atol=1e-12)


def test_binning_rules_on_constructed_points():
    sc = ScanContext(voxel_size=None)
    pts = np.array(
        [
            [1.0, 0.0, -1.0],  # y == 0 -> 0.001: ring 0, sector 0, h = 1.0
            [1.0, 0.0, 0.5],  # same cell, higher: 2.5 wins
            [-1.0, 1e-9, -3.0],  # h = -1 -> cell stays 0 (max(0, h))
            [0.0, -5.0, 1.0],  # x == 0 -> 0.001: 270 deg -> sector 45, ring 1
            [200.0, 200.0, 0.0],  # beyond 80 m -> last ring, 45 deg -> sector 7
        ]
    )
    d = sc.compute(pts)
    assert d[0, 0] == 2.5
    assert d[0, 29] == 0.0
    assert d[1, 45] == 3.0
    assert d[19, 7] == 2.0
    assert np.count_nonzero(d) == 3


def test_bad_input_raises_clear_errors():
    sc = ScanContext()
    with pytest.raises(InputError, match="shape"):
        sc.compute(np.zeros((10, 2)))
    with pytest.raises(InputError, match=r"frame 7: points: expected shape \(P, 3\)"):
        sc.compute(np.zeros((4, 2)), frame=7)
    with pytest.raises(InputError, match="point 1 has NaN"):
        sc.compute(np.array([[0.0, 1.0, 2.0], [0.0, 1.0, np.nan]]))
    with pytest.raises(InputError, match="NaN"):
        ScanContext(voxel_size=None).compute(np.array([[0.0, 1.0, np.inf]]))
    with pytest.raises(InputError, match=r"\(N, 20, 60\)"):
        sc.similarity_many(np.zeros((20, 60)), np.zeros((3, 20, 61)))
    with pytest.raises(InputError, match="voxel_size"):
        ScanContext(voxel_size=0.0)
