"""Precomputed descriptors, the descriptor registry and the shared Protocol."""

from __future__ import annotations

import numpy as np
import pytest

from msa_slam.descriptors import DESCRIPTOR_NAMES, Descriptor, PrecomputedDescriptors, ScanContext, make_descriptor
from msa_slam.errors import InputError


@pytest.fixture
def npy(tmp_path):
    path = tmp_path / "desc.npy"
    np.save(path, np.arange(24, dtype=np.float32).reshape(4, 2, 3))
    return path


def test_precomputed_lookup_any_shape(npy):
    pre = PrecomputedDescriptors(npy, n_frames=4)
    assert len(pre) == 4 and pre.shape == (2, 3)
    np.testing.assert_array_equal(pre.compute(None, frame=2), np.arange(12, 18).reshape(2, 3))
    assert pre.compute(np.zeros((5, 3)), frame=0).dtype == np.float64


def test_precomputed_inverse_l2_similarity(npy):
    pre = PrecomputedDescriptors(npy)
    a, b = pre.compute(None, 0), pre.compute(None, 1)  # differ by 6 in each of 6 entries: L2 = sqrt(216)
    assert pre.similarity(a, b) == pytest.approx(1.0 / (1.0 + np.sqrt(216.0)))
    np.testing.assert_allclose(pre.similarity_many(a, pre.descriptors), 1.0 / (1.0 + np.sqrt(216.0) * np.arange(4)))


def test_precomputed_scan_context_similarity(tmp_path):
    rng = np.random.default_rng(1)
    base = rng.random((20, 60))
    path = tmp_path / "sc.npy"
    np.save(path, np.stack([base, np.roll(base, 5, axis=1)]))
    pre = PrecomputedDescriptors(path, similarity="scan_context")
    assert pre.similarity(pre.compute(None, 0), pre.compute(None, 1)) == pytest.approx(1.0)


def test_precomputed_errors(npy, tmp_path):
    with pytest.raises(InputError, match="file not found"):
        PrecomputedDescriptors(tmp_path / "missing.npy")
    corrupt = tmp_path / "corrupt.npy"
    corrupt.write_bytes(b"\x93NUMPY garbage")
    with pytest.raises(InputError, match="not a readable .npy"):
        PrecomputedDescriptors(corrupt)
    huge = tmp_path / "huge.npy"  # a valid header claiming 48 TB, then 800 bytes: refused before any allocation
    with huge.open("wb") as file:
        np.lib.format.write_array_header_1_0(
            file, {"descr": "<f8", "fortran_order": False, "shape": (60, 10**6, 10**5)}
        )
        file.write(bytes(800))
    with pytest.raises(InputError, match="huge.npy is not a readable .npy array \\(truncated or corrupt"):
        PrecomputedDescriptors(huge)
    for name, values in (("complex.npy", np.ones((5, 4), complex)), ("bool.npy", np.ones((5, 4), bool))):
        np.save(tmp_path / name, values)
        with pytest.raises(InputError, match=f"{name} holds {values.dtype} values; expected real numbers"):
            PrecomputedDescriptors(tmp_path / name)
    np.savez(tmp_path / "both.npz", a=np.ones((5, 4)))
    with pytest.raises(InputError, match="both.npz is a .npz archive; expected one .npy array"):
        PrecomputedDescriptors(tmp_path / "both.npz")
    with pytest.raises(InputError, match="has 4 frames, the sequence has 5"):
        PrecomputedDescriptors(npy, n_frames=5)
    flat = tmp_path / "flat.npy"
    np.save(flat, np.zeros(7))
    with pytest.raises(InputError, match=r"must hold an array \(N, ...\) of N descriptors, got shape \(7,\)"):
        PrecomputedDescriptors(flat)
    nan = tmp_path / "nan.npy"
    np.save(nan, np.array([[0.0, 1.0], [np.nan, 0.0]]))
    with pytest.raises(InputError, match="frame 1 has NaN"):
        PrecomputedDescriptors(nan)
    pre = PrecomputedDescriptors(npy)
    with pytest.raises(InputError, match=r"frames 0..3, asked for 4"):
        pre.compute(None, frame=4)
    with pytest.raises(InputError, match="similarity must be one of"):
        PrecomputedDescriptors(npy, similarity="cosine")


def test_registry_names_and_errors(npy):
    assert isinstance(make_descriptor("sc"), ScanContext)
    assert isinstance(make_descriptor("Scan_Context", n_ring=10).shape, tuple)
    assert make_descriptor("scan_context", n_ring=10).shape == (10, 60)
    assert isinstance(make_descriptor("precomputed", path=npy), PrecomputedDescriptors)
    with pytest.raises(
        InputError, match="unknown name 'nope'; choose one of sc, scan_context, ot, overlap_transformer, precomputed"
    ):
        make_descriptor("nope")
    with pytest.raises(InputError, match="bad parameters"):
        make_descriptor("sc", rings=3)
    assert set(DESCRIPTOR_NAMES) == {"sc", "scan_context", "ot", "overlap_transformer", "precomputed"}


def test_all_descriptors_satisfy_protocol(npy):
    assert isinstance(ScanContext(), Descriptor)
    assert isinstance(PrecomputedDescriptors(npy), Descriptor)
