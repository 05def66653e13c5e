"""OverlapTransformer: range projection and network against the golden vectors (Ma et al., RA-L 2022)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import shared_path
from msa_slam.descriptors.range_image import range_projection
from msa_slam.errors import InputError


def load_scan(name: str) -> np.ndarray:
    raw = np.fromfile(shared_path("data", "kitti_scans_00", f"{name}.bin"), dtype=np.float32)
    return raw.reshape(-1, 4)


@pytest.fixture(scope="module")
def golden():
    return np.load(shared_path("parity", "overlap_transformer_golden.npz"))


def test_range_images_match_golden_exactly(golden):
    scans = [load_scan(n) for n in ("000000", "000005", "000015")]
    c, s = 0.0, 1.0  # 90 deg about z, applied in float32 like the golden's generator
    turned = scans[0][:, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float32).T
    for k, points in enumerate([*scans, turned]):
        image = range_projection(points)
        assert image.dtype == np.float32 and image.shape == (64, 900)
        np.testing.assert_array_equal(image, golden["range_images"][k])


def test_range_projection_keeps_nearest_and_drops_out_of_range():
    points = np.array([[10.0, 0.0, 0.0], [5.0, 0.0, 0.0], [100.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    image = range_projection(points)
    assert np.count_nonzero(image >= 0) == 1
    row, col = np.argwhere(image >= 0)[0]
    assert image[row, col] == 5.0
    assert col == 450  # yaw 0 lands mid-image


# ---- network (needs torch) ---------------------------------------------------------------------


UNUSED = ("bn", "linear.", "linear1.", "linear2.", "linear3.", "net_vlad.bn2.")


def deterministic_state_dict(torch):
    """Weights of ../shared/parity/README.md: rng(k) normals / sqrt(fan-in) for entry k (file order).
    Tensors not read at inference (batch norms, unused heads) only need the right shape: they are
    stored as broadcast views so the file stays small."""
    state = {}
    k = 0
    for line in shared_path("data", "overlap_transformer_state_dict.txt").read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        name, shape_text = line.split(" ", 1)
        shape = tuple(int(v) for v in shape_text.strip("() \n").split(",") if v.strip())
        if name.startswith(UNUSED):
            state[name] = torch.zeros(()).expand(shape)
        else:
            numel = int(np.prod(shape))
            fan = int(np.prod(shape[1:])) if len(shape) >= 2 else numel
            arr = np.random.default_rng(k).standard_normal(numel).reshape(shape) / np.sqrt(fan)
            state[name] = torch.from_numpy(arr.astype(np.float32))
        k += 1
    return state


@pytest.fixture(scope="module")
def torch_mod():
    return pytest.importorskip("torch", reason="torch not installed (optional extra msa-slam[ot])")


@pytest.fixture(scope="module")
def state(torch_mod):
    return deterministic_state_dict(torch_mod)


@pytest.fixture(scope="module")
def weights(torch_mod, state, tmp_path_factory):
    path = tmp_path_factory.mktemp("ot") / "weights.pth.tar"
    torch_mod.save({"state_dict": state}, path)
    return path


@pytest.fixture(scope="module")
def model(weights):
    from msa_slam.descriptors.overlap_transformer import OverlapTransformer

    return OverlapTransformer(weights)


def test_network_reproduces_golden_descriptors(model, golden):
    got = model.descriptors_from_range_images(golden["range_images"])
    np.testing.assert_allclose(got, golden["descriptors"], atol=1e-5, rtol=0)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-6)


def test_compute_from_raw_scan_and_similarity(model, golden):
    d0 = model.compute(load_scan("000000"))
    np.testing.assert_allclose(d0, golden["descriptors"][0], atol=1e-5, rtol=0)
    d1 = golden["descriptors"][1]
    assert model.similarity(d0, d1) == pytest.approx(1.0 / (1.0 + np.linalg.norm(d0.astype(np.float64) - d1)), rel=1e-12)
    assert model.similarity(d0, d0) == 1.0
    np.testing.assert_allclose(model.similarity_many(d0, golden["descriptors"][:2]), [model.similarity(d0, d0), model.similarity(d0, d1)], atol=1e-6)


def test_registry_builds_overlap_transformer(weights):
    from msa_slam.descriptors import make_descriptor

    assert make_descriptor("ot", weights=weights).shape == (256,)


def test_missing_weights_file(torch_mod, tmp_path):
    from msa_slam.descriptors.overlap_transformer import load_network

    with pytest.raises(InputError, match="weights file not found"):
        load_network(tmp_path / "nope.pth")


def test_corrupt_weights_file(torch_mod, tmp_path):
    from msa_slam.descriptors.overlap_transformer import load_network

    bad = tmp_path / "bad.pth"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="cannot read weights file"):
        load_network(bad)


def test_state_dict_mismatch_named(torch_mod, state, tmp_path):
    from msa_slam.descriptors.overlap_transformer import load_network

    state = {name: torch_mod.zeros(()).expand(t.shape) for name, t in state.items()}  # right shapes, tiny files
    missing = dict(state)
    del missing["net_vlad.hidden1_weights"]
    torch_mod.save({"state_dict": missing}, tmp_path / "missing.pth")
    with pytest.raises(InputError, match="lacks weights used at inference: net_vlad.hidden1_weights"):
        load_network(tmp_path / "missing.pth")
    wrong = dict(state)
    wrong["conv3.weight"] = torch_mod.zeros(64, 32, 5, 1)
    torch_mod.save({"state_dict": wrong}, tmp_path / "wrong.pth")
    with pytest.raises(InputError, match=r"'conv3.weight' has shape \(64, 32, 5, 1\), expected \(64, 32, 3, 1\)"):
        load_network(tmp_path / "wrong.pth")
    extra = dict(state)
    extra["head.weight"] = torch_mod.zeros(3)
    torch_mod.save({"state_dict": extra}, tmp_path / "extra.pth")
    with pytest.raises(InputError, match="unexpected weights: head.weight"):
        load_network(tmp_path / "extra.pth")
    torch_mod.save({"weights": 1}, tmp_path / "nostate.pth")
    with pytest.raises(InputError, match="lacks weights used at inference"):
        load_network(tmp_path / "nostate.pth")


def test_missing_torch_is_a_clear_error(monkeypatch, tmp_path):
    from msa_slam.descriptors.overlap_transformer import load_network

    monkeypatch.setitem(sys.modules, "torch", None)  # makes `import torch` raise ImportError
    with pytest.raises(InputError, match=r"torch is not installed.*msa-slam\[ot\]"):
        load_network(tmp_path / "w.pth")
