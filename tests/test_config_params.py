"""Batch config: `-p key=value` routing and the checks that keep a bad value from becoming a run."""

from __future__ import annotations

import re

import pytest
import yaml

from msa_slam.errors import InputError
from msa_slam.pipeline.config import apply_params, load_config, make_config, read_config_file


@pytest.fixture
def base():
    return make_config(dataset="sim:test")


def test_bare_mode_with_a_sampler_mode_says_how_to_reach_the_sampler(base):
    message = (
        "--param mode=fast: `mode` is the config's mode (oracle, realistic); "
        "for the msa sampler's mode write sampler.mode=fast"
    )
    with pytest.raises(InputError, match=re.escape(message)):
        apply_params(base, ["mode=fast"])
    routed = apply_params(base, ["sampler.mode=fast", "mode=realistic"])
    assert routed.sampler_params == {"mode": "fast"} and routed.mode == "realistic"


def test_bare_mode_valid_for_neither_gets_the_config_error(base):
    with pytest.raises(InputError, match=r"config: mode: Input should be 'oracle' or 'realistic'"):
        apply_params(base, ["mode=psychic"])


@pytest.mark.parametrize(
    "override, fragment",
    [
        ("alpha=.nan", "sampler 'msa': alpha=nan is not allowed; expected a finite number > 0"),
        ("beta=.inf", "sampler 'msa': beta=inf is not allowed; expected a finite number > 0"),
        ("sampler.beta=-.inf", "sampler 'msa': beta=-inf is not allowed; expected a finite number > 0"),
        ("use_rho=maybe", "sampler 'msa': use_rho='maybe' is not allowed; expected true or false"),
        ("lambda_u=inf", "sampler 'msa': lambda_u='inf' is not allowed; expected a finite number > 0"),
        ("window=abc", "sampler 'msa': window='abc' is not allowed; expected an integer >= 3"),
        ("window=30", "window=30: up to 2^29 - 2 = 536870910 candidates"),
        ("descriptor.max_radius=.nan", "descriptor_params: max_radius=nan is not allowed; expected a finite number"),
        ("loop_radius=.inf", "loop_radius: Input should be a finite number"),
        ("verifier.max_residual=.nan", "verifier.max_residual: Input should be a finite number"),
    ],
)
def test_bad_values_are_refused_naming_the_key(base, override, fragment):
    with pytest.raises(InputError, match=re.escape(fragment)):
        apply_params(base, [override])


def test_constant_sampler_distance_must_be_a_number():
    config = make_config(dataset="sim:test", sampler="constant")
    with pytest.raises(
        InputError, match=re.escape("sampler 'constant': distance='abc' is not allowed; expected a finite number >= 0")
    ):
        apply_params(config, ["distance=abc"])


def test_config_yaml_round_trips(base, tmp_path):
    config = apply_params(base, ["alpha=2.5", "sampler.mode=fast", "use_rho=false", "loop_radius=4"])
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config.dump()))
    assert "null" not in yaml.safe_dump(config.dump()["sampler_params"])
    assert load_config(path) == config


def test_nan_in_a_config_file_is_refused(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text("dataset: sim:test\nsampler_params:\n  alpha: .nan\n")
    with pytest.raises(InputError, match=re.escape("sampler_params.alpha=nan is not allowed")):
        load_config(path)


def test_a_config_file_without_the_dataset_is_completed_by_the_options(tmp_path):
    """`run --config FILE -d DATASET`: the file is checked on its own as read (a missing dataset is no error)
    and the whole config validated once the options are in."""
    from msa_slam.cli.run import batch_config

    path = tmp_path / "c.yaml"
    path.write_text("sampler: constant\nsampler_params: {distance: 2}\n")
    config = batch_config(path, {"dataset": "sim:test"}, [])
    assert (config.dataset, config.sampler, config.sampler_params) == ("sim:test", "constant", {"distance": 2})
    with pytest.raises(InputError, match="--dataset is required"):
        batch_config(path, {}, [])


@pytest.mark.parametrize(
    "text, problem",
    [
        ("windw: 3\n", "unknown key 'windw'; valid keys: dataset, dataset_kind, source, "),
        ("similarity_threshold: high\n", "similarity_threshold: Input should be a valid number"),
        ("min_frame_gap: -1\n", "min_frame_gap: Input should be greater than or equal to 0"),
        ("verifier:\n  max_residul: 0.2\n", "unknown key 'verifier.max_residul'; valid keys: voxel_size, "),
        ("source: {frist: 3}\n", "unknown key 'source.frist'; valid keys: topic, "),
        ("sampler: msa\nsampler_params: {windw: 3}\n", "sampler 'msa': unknown parameter(s) windw; it takes: window="),
        ("sampler_params: {alpha: .inf}\n", "sampler_params.alpha=inf is not allowed; expected a finite number"),
        ("1: 2\n", "key 1 is not a name; valid keys: dataset, "),
        ("verifier: {1: 2}\n", "verifier: key 1 is not a name; valid keys: voxel_size, "),
        ("source: {first: 0, 2: 3}\n", "source: key 2 is not a name; valid keys: topic, gt, "),
        ("odometry_params: {1: 2}\n", "odometry_params: key 1 is not a parameter name"),
        ("odometry: {1: 2}\n", "odometry: Input should be a valid string"),
    ],
)
def test_a_bad_key_in_a_config_file_names_the_file(tmp_path, text, problem):
    path = tmp_path / "config.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=f"^{re.escape(f'{path}: {problem}')}"):
        read_config_file(path)


def test_sampler_params_of_a_file_without_sampler_wait_for_the_options(tmp_path):
    """Whose parameters they are is the --sampler option's to say: checked (as the config's) after the merge."""
    from msa_slam.cli.run import batch_config

    path = tmp_path / "c.yaml"
    path.write_text("sampler_params: {distance: 2}\n")
    assert read_config_file(path) == {"sampler_params": {"distance": 2}}
    assert batch_config(path, {"dataset": "sim:test", "sampler": "constant"}, []).sampler_params == {"distance": 2}
    with pytest.raises(InputError, match=re.escape("config: sampler 'msa': unknown parameter(s) distance")):
        batch_config(path, {"dataset": "sim:test"}, [])


@pytest.mark.parametrize(
    "command, text, problem",
    [
        ("run", "windw: 3\n", "unknown key 'windw'; valid keys: "),
        ("compare", "verifier: {max_residual: x}\n", "verifier.max_residual: Input should be a valid number"),
        ("online", "windw: 3\n", "unknown key 'windw'; valid keys: "),
        (
            "online",
            "cloud_store: disk\nupdate_iterations: -1\n",  # online's own keys: checked as OnlineConfig
            "update_iterations: Input should be greater than or equal to 0",
        ),
        ("run", "cloud_store: disk\n", "unknown key 'cloud_store'; valid keys: "),
    ],
)
def test_config_file_errors_of_the_commands_name_the_file(tmp_path, command, text, problem):
    from typer.testing import CliRunner

    from msa_slam.cli import app

    path = tmp_path / "my-config.yaml"
    path.write_text(text)
    result = CliRunner().invoke(
        app, [command, "--config", str(path), "--dataset", "sim:test", "--out", str(tmp_path / "out"), "--quiet"]
    )
    assert isinstance(result.exception, InputError), result.output
    assert str(result.exception).startswith(f"{path}: {problem}")
    assert not (tmp_path / "out").exists()
