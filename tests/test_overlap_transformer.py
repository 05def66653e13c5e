"""OverlapTransformer: range projection and network against the golden vectors (Ma et al., RA-L 2022)."""

from __future__ import annotations

import re
import sys

import numpy as np
import pytest
from conftest import shared_path
from helpers.scans import load_scan

from msa_slam.descriptors.range_image import projection_coordinates, range_projection
from msa_slam.errors import InputError


@pytest.fixture(scope="module")
def golden():
    return np.load(shared_path("parity", "overlap_transformer_golden.npz"))


BORDER_ULPS = 8  # float32 ulps of a row/column value within which a point counts as on a pixel border


def border_tolerant_mismatches(image: np.ndarray, golden: np.ndarray, points: np.ndarray) -> list:
    """Pixels where `golden` differs from `image` in a way a point on a pixel border cannot explain.

    A point whose float32 row or column is within BORDER_ULPS of an integer may land on either side
    (CPUs round arctan2 differently: 668.99994 -> 668 or 669). At a pixel such points can reach, the
    nearest point wins, so the golden value must be the nearest of the points certainly there and
    any of the border points that can land there (or -1 when none is certainly there).
    """
    row, col, depth = projection_coordinates(points)
    height, width = image.shape

    def options(value, size):
        near = np.abs(value - np.round(value)) <= BORDER_ULPS * np.spacing(np.abs(value))
        low = np.clip(np.floor(value), 0, size - 1).astype(int)
        other = np.clip(np.where(value - np.round(value) < 0, low + 1, low - 1), 0, size - 1)
        return low, np.where(near, other, low), near

    row_a, row_b, row_near = options(row, height)
    col_a, col_b, col_near = options(col, width)
    border = row_near | col_near
    bad = []
    for r, c in np.argwhere(image != golden):
        certain = depth[~border & (row_a == r) & (col_a == c)]
        reach = border & (((row_a == r) | (row_b == r)) & ((col_a == c) | (col_b == c)))
        floor = certain.min() if certain.size else np.inf
        allowed = {float(floor) if certain.size else -1.0} | {float(d) for d in depth[reach] if d < floor}
        if not reach.any() or float(golden[r, c]) not in allowed:
            bad.append((int(r), int(c), float(image[r, c]), float(golden[r, c])))
    return bad


def golden_scans():
    scans = [load_scan(n)[:, :3] for n in ("000000", "000005", "000015")]
    c, s = 0.0, 1.0  # 90 deg about z, applied in float32 like the golden's generator
    turned = scans[0] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float32).T
    return [*scans, turned]


def test_range_images_match_golden_up_to_border_points(golden):
    for k, points in enumerate(golden_scans()):
        image = range_projection(points)
        assert image.dtype == np.float32 and image.shape == (64, 900)
        assert border_tolerant_mismatches(image, golden["range_images"][k], points) == []


def test_border_tolerance_accepts_only_border_points():
    yaw = (669.0 / 450.0 - 1.0) * np.pi  # column 669.0 exactly, up to float32 rounding
    points = np.array([[10 * np.cos(-yaw), 10 * np.sin(-yaw), 0.0], [20.0, 0.0, 0.0]], dtype=np.float32)
    _, col, _ = projection_coordinates(points)
    assert abs(col[0] - 669.0) <= BORDER_ULPS * np.spacing(np.float32(669.0))
    image = range_projection(points)
    ((r, c),) = np.argwhere(image == image[:, 668:670].max())
    other = image.copy()  # another CPU's outcome: the border point on the other side of column 669
    other[r, c], other[r, 1337 - c] = -1.0, image[r, c]
    assert border_tolerant_mismatches(image, other, points) == []
    wrong = image.copy()  # the ordinary point (column 450) must match exactly
    wrong[:, 450] = np.roll(image[:, 450], 1)
    assert border_tolerant_mismatches(image, wrong, points) != []
    wrong = image.copy()  # and the border point may only move by one column
    wrong[r, c], wrong[r, 671] = -1.0, image[r, c]
    assert border_tolerant_mismatches(image, wrong, points) != []


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
    assert model.similarity(d0, d1) == pytest.approx(
        1.0 / (1.0 + np.linalg.norm(d0.astype(np.float64) - d1)), rel=1e-12
    )
    assert model.similarity(d0, d0) == 1.0
    # d0 matches golden[0] only to the network's cross-CPU tolerance (1e-5 above), so compare like with like
    bank = golden["descriptors"][:2]
    expected = [model.similarity(d0, bank[0]), model.similarity(d0, d1)]
    np.testing.assert_allclose(model.similarity_many(d0, bank), expected, rtol=1e-12)


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

    monkeypatch.setitem(sys.modules, "torch", None)  # makes `import torch` raise ImportError, installed or not
    # the network module, if an earlier test imported it with torch, must be imported afresh as without torch
    monkeypatch.delitem(sys.modules, "msa_slam.descriptors._ot_network", raising=False)
    with pytest.raises(InputError, match=r"torch is not installed.*msa-slam\[ot\]"):
        load_network(tmp_path / "w.pth")


def test_published_checkpoint_plain_state_dict_and_converted_file_agree(torch_mod, state, golden, tmp_path):
    """The authors' file holds epoch, optimizer and 'state_dict'; a plain or DataParallel state_dict works too."""
    from msa_slam.descriptors.overlap_transformer import OverlapTransformer, convert_checkpoint

    published = tmp_path / "pretrained_overlap_transformer.pth.tar"
    torch_mod.save(
        {"epoch": 30, "state_dict": state, "optimizer": {"state": {}, "param_groups": [{"lr": 1e-5}]}}, published
    )
    torch_mod.save(state, tmp_path / "plain.pth")
    torch_mod.save({f"module.{k}": v for k, v in state.items()}, tmp_path / "parallel.pth")
    converted = convert_checkpoint(published, tmp_path / "converted.pth")
    assert set(torch_mod.load(converted, weights_only=True)) < set(state)  # inference weights only
    images = golden["range_images"][:1]
    for path in (published, tmp_path / "plain.pth", tmp_path / "parallel.pth", converted):
        got = OverlapTransformer(path).descriptors_from_range_images(images)
        np.testing.assert_allclose(got, golden["descriptors"][:1], atol=1e-5, rtol=0)
    with pytest.raises(InputError, match="converted.pth exists"):
        convert_checkpoint(published, converted)


def test_wrong_files_name_what_is_expected(torch_mod, tmp_path):
    from msa_slam.descriptors import make_descriptor
    from msa_slam.descriptors.overlap_transformer import WEIGHTS_URL, load_network

    torch_mod.save([1, 2], tmp_path / "list.pth")
    with pytest.raises(InputError, match="list.pth is not an OverlapTransformer checkpoint.*holds list"):
        load_network(tmp_path / "list.pth")
    with pytest.raises(InputError, match="pretrained_overlap_transformer.pth.tar"):
        load_network(tmp_path / "nope.pth")
    url = re.escape(WEIGHTS_URL)
    with pytest.raises(InputError, match=f"missing a required argument: .weights.*{url}.*-p weights=FILE"):
        make_descriptor("ot")


@pytest.mark.parametrize("command", ["run", "compare", "online"])
def test_help_says_where_the_weights_are(command):
    from typer.testing import CliRunner

    from msa_slam.cli import app
    from msa_slam.descriptors.overlap_transformer import WEIGHTS_URL

    shown = CliRunner().invoke(app, [command, "--help"], env={"COLUMNS": "80"}).output
    assert WEIGHTS_URL.split("/view")[0] in shown and "-p weights=FILE" in shown
