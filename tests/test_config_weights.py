"""`-p weights=FILE` selects the OverlapTransformer's weights (as the docs and --help write it), in either
order with the descriptor; a missing weights file is refused with the overrides, before any scan."""

from __future__ import annotations

import re

import pytest
from helpers.cli import main_in_process

from msa_slam.errors import InputError
from msa_slam.pipeline.config import apply_params, make_config


@pytest.fixture
def weights(tmp_path):
    path = tmp_path / "pretrained_overlap_transformer.pth.tar"
    path.write_bytes(b"not read before the descriptor is built")
    return path


@pytest.mark.parametrize("order", ["descriptor first", "weights first"])
def test_bare_weights_reach_the_overlap_transformer(weights, order):
    params = [f"weights={weights}", "descriptor=ot"]
    config = apply_params(make_config(dataset="x"), params if order == "weights first" else params[::-1])
    assert config.descriptor == "ot"
    assert config.descriptor_params == {"weights": str(weights)} and config.sampler_params == {}


def test_bare_weights_same_as_the_dotted_key(weights):
    base = make_config(dataset="x", descriptor="overlap_transformer", descriptor_params={"weights": str(weights)})
    assert apply_params(base.model_copy(update={"descriptor_params": {}}), [f"weights={weights}"]) == base
    assert apply_params(
        make_config(dataset="x"), ["descriptor=ot", f"descriptor.weights={weights}"]
    ).descriptor_params == {"weights": str(weights)}


def test_weights_without_the_overlap_transformer_say_how(weights):
    message = f"--param weights={weights}: the weights file is the OverlapTransformer's, but the descriptor is 'sc'"
    with pytest.raises(InputError, match=re.escape(message) + ".*--descriptor ot"):
        apply_params(make_config(dataset="x"), [f"weights={weights}"])


def test_unknown_bare_key_still_lists_what_exists():
    with pytest.raises(
        InputError,
        match=r"--param 'wieghts': not a config key \(dataset, .*similarity_threshold"
        r".*\), a parameter of sampler 'msa' \(window, .*lambda_u.*\) nor weights",
    ):
        apply_params(make_config(dataset="x"), ["wieghts=a.pth"])


def test_overlap_transformer_weights_checked_when_the_config_is_made(tmp_path):
    with pytest.raises(
        InputError,
        match=r"descriptor 'ot' needs its weights file, -p weights=FILE: .*"
        r"pretrained_overlap_transformer\.pth\.tar",
    ):
        apply_params(make_config(dataset="x", descriptor="ot"), [])
    missing = tmp_path / "missing.pth"
    with pytest.raises(InputError, match=re.escape(f"descriptor 'ot': weights file not found: {missing}")):
        apply_params(make_config(dataset="x"), ["descriptor=ot", f"weights={missing}"])


def test_cli_refuses_a_missing_weights_file_before_reading_scans(tmp_path, monkeypatch, capsys):
    # the dataset does not exist either: the weights come first, one line, nothing written
    missing = tmp_path / "missing.pth"
    monkeypatch.setenv("MSA_SLAM_CACHE", str(tmp_path / "cache"))
    result = main_in_process(
        monkeypatch,
        capsys,
        "run",
        "--dataset",
        str(tmp_path / "no-data"),
        "--descriptor",
        "ot",
        "-p",
        f"weights={missing}",
        "--out",
        str(tmp_path / "out"),
    )
    assert result.returncode == 2
    assert result.stderr.startswith(f"error: config: descriptor 'ot': weights file not found: {missing}; ")
    assert len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()


def test_online_config_routes_and_checks_the_weights(weights, tmp_path):
    from msa_slam.pipeline.config import apply_online_params

    config = apply_online_params({"dataset": "x"}, ["descriptor=ot", f"weights={weights}"])
    assert config.descriptor_params == {"weights": str(weights)}
    with pytest.raises(InputError, match="weights file not found: .*nope.pth"):
        apply_online_params({"dataset": "x"}, ["descriptor=ot", f"weights={tmp_path / 'nope.pth'}"])


@pytest.mark.parametrize(
    "args, message",
    [
        (["--descriptor", "foo"], "error: config: descriptor: unknown name 'foo'; choose one of sc, "),
        (
            ["--descriptor", "precomputed"],
            "error: config: descriptor 'precomputed' needs its descriptor file, -p descriptor.path=FILE.npy",
        ),
    ],
)
def test_cli_refuses_a_bad_descriptor_before_simulating_the_dataset(tmp_path, monkeypatch, capsys, args, message):
    """sim:test is simulated on first use: a typo in the descriptor must not cost that first."""
    monkeypatch.setenv("MSA_SLAM_CACHE", str(tmp_path / "cache"))
    result = main_in_process(monkeypatch, capsys, "run", "--dataset", "sim:test", *args, "--out", str(tmp_path / "out"))
    assert result.returncode == 2 and result.stderr.startswith(message), result.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()
