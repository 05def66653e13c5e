"""Typed sampler parameters: each sampler's pydantic model, held by a run's config as a tagged union (the
sampler's name its tag), checked once when the config is built (no sampler is built to learn whether they are
valid), refused with the sampler, the key and what it allows from every way of giving them (-p, config files,
grid params and sweeps, the command line), and echoed as given."""

from __future__ import annotations

import re
import typing

import pytest
import yaml
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.errors import InputError
from msa_slam.experiments.grid import parse_grid
from msa_slam.pipeline.config import OnlineConfig, RunConfig, apply_online_params, apply_params, make_config
from msa_slam.sampling import SAMPLERS, SamplerChoice, SamplerParams, build_sampler, check_sampler_params
from msa_slam.sampling.baselines import ConstantParams
from msa_slam.sampling.msa.params import MSAParams

runner = CliRunner()


def test_every_sampler_owns_a_strict_documented_model_and_the_union_holds_them_all():
    union = typing.get_args(typing.get_args(SamplerChoice)[0])
    assert {model.NAME for model in union} == set(SAMPLERS)
    for name, cls in SAMPLERS.items():
        model = cls.Params
        assert model in union and model.NAME == name and model.model_fields["sampler"].default == name
        assert model.model_config["extra"] == "forbid"
        assert all(f.description for key, f in model.model_fields.items() if key != "sampler"), name


def test_the_config_holds_typed_parameters_and_echoes_them_as_given():
    config = make_config(dataset="x", sampler="constant", sampler_params={"distance": 2})
    assert isinstance(config.sampler_params, ConstantParams) and config.sampler_params.distance == 2.0
    assert config.dump()["sampler_params"] == {"distance": 2}  # not 2.0, and no defaults: config.yaml unchanged
    assert type(config.dump()["sampler_params"]["distance"]) is int
    assert make_config(dataset="x").dump()["sampler_params"] == {}
    assert isinstance(make_config(dataset="x").sampler_params, MSAParams)


def test_the_sampler_built_from_the_config_has_its_typed_values():
    config = make_config(dataset="x", sampler_params={"window": 8.0, "lambda_u": 5})
    sampler = build_sampler(config.sampler_params)
    assert sampler.window_size == 8 and type(sampler.window_size) is int and sampler.lambda_u == 5.0


def test_no_sampler_is_built_to_check_a_config(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("a sampler was built")

    for cls in SAMPLERS.values():
        monkeypatch.setattr(cls, "__init__", refuse)
    config = apply_params(make_config(dataset="x"), ["window=8", "sampler.mode=fast", "mode=realistic"])
    assert config.sampler_params.window == 8 and config.sampler_params.mode == "fast"
    apply_online_params({"dataset": "x", "sampler": "entropy"}, ["bins=20"])
    with pytest.raises(InputError, match="window=2 is not allowed"):
        apply_params(config, ["window=2"])


BAD_WINDOW = "sampler 'msa': window='abc' is not allowed; expected an integer >= 3"


@pytest.mark.parametrize("override", ["window=abc", "sampler.window=abc", "sampler_params.window=abc"])
def test_every_param_spelling_gets_the_same_message(override):
    with pytest.raises(InputError, match=f"^config: {re.escape(BAD_WINDOW)}$"):
        apply_params(make_config(dataset="x"), [override])


@pytest.mark.parametrize("model", [RunConfig, OnlineConfig])
def test_an_unknown_key_lists_the_samplers_keys_with_their_defaults(model):
    config = model(dataset="x", sampler="entropy")
    with pytest.raises(
        InputError,
        match=re.escape(
            "sampler 'entropy': unknown parameter(s) bns; it takes: "
            "threshold=0.05, max_distance=5.0, bins=10, min_motion=0.0, "
            "min_rotation=0.0"
        ),
    ):
        apply_params(config, ["sampler_params.bns=20"])


@pytest.mark.parametrize(
    "params, message",
    [
        ({"bins": 0}, "sampler 'entropy': bins=0 is not allowed; expected an integer >= 1 and <= 100"),
        ({"bins": "10"}, "sampler 'entropy': bins='10' is not allowed; expected an integer >= 1 and <= 100"),
        ({"threshold": True}, "sampler 'entropy': threshold=True is not allowed; expected a finite number >= 0"),
        (
            {"max_distance": float("inf")},
            "sampler 'entropy': max_distance=inf is not allowed; expected a finite number > 0",
        ),
    ],
)
def test_bad_values_name_the_sampler_the_key_and_the_range(params, message):
    with pytest.raises(InputError, match=f"^config: {re.escape(message)}$"):
        make_config(dataset="x", sampler="entropy", sampler_params=params)
    with pytest.raises(InputError, match=f"^{re.escape(message)}$"):
        check_sampler_params("entropy", params)


def test_an_unknown_sampler_lists_the_samplers():
    with pytest.raises(
        InputError,
        match=re.escape("config: unknown sampler 'msb'; available: all, constant, entropy, spaciousness, msa"),
    ):
        make_config(dataset="x", sampler="msb")


def test_the_sampler_is_chosen_by_the_config_not_among_its_parameters():
    with pytest.raises(InputError, match="'sampler' is not a sampler parameter; choose the sampler with the config's"):
        make_config(dataset="x", sampler_params={"sampler": "constant"})
    config = make_config(dataset="x", sampler_params={"window": 8})
    with pytest.raises(ValueError, match="sampler 'constant' assigned without its parameters"):
        config.sampler = "constant"


def test_a_config_file_with_bad_sampler_parameters_names_the_file(tmp_path):
    from msa_slam.pipeline.config import read_config_file

    path = tmp_path / "c.yaml"
    path.write_text("sampler: constant\nsampler_params: {distance: -1}\n")
    with pytest.raises(
        InputError,
        match=f"^{re.escape(str(path))}: sampler 'constant': distance=-1 is not allowed; "
        "expected a finite number >= 0$",
    ):
        read_config_file(path)


def _grid(method: dict) -> dict:
    return {"datasets": ["sim:test"], "pipeline": "batch", "samplers": [method]}


@pytest.mark.parametrize(
    "method, message",
    [
        (
            {"sampler": "msa", "params": {"window": 2}},
            "sampler 'msa': window=2 is not allowed; expected an integer >= 3",
        ),
        (
            {"sampler": "msa", "sweep": {"lambda_l": [0.5, 4]}},
            "sampler 'msa': lambda_l=4.0 > lambda_u=3.0 is not allowed; expected lambda_l <= lambda_u",
        ),
        (
            {"sampler": "constant", "params": {"distnce": 2}},
            "sampler 'constant': unknown parameter(s) distnce; it takes: "
            "distance=1.0, min_motion=0.0, min_rotation=0.0",
        ),
    ],
)
def test_grid_params_and_sweeps_are_refused_naming_the_cell_and_the_key(method, message):
    with pytest.raises(InputError, match=re.escape(message)) as err:
        parse_grid(_grid(method), "g.yaml")
    assert str(err.value).startswith("g.yaml: cell ")


@pytest.mark.parametrize("command", ["run", "online", "compare"])
def test_the_command_line_refuses_bad_sampler_parameters_before_any_work(command, tmp_path):
    out = tmp_path / "out"
    args = [command, "--dataset", "sim:test", "--out", str(out), "--quiet", "-p", "lambda_u=0"]
    result = runner.invoke(app, args if command == "compare" else [*args, "--sampler", "msa"])
    assert isinstance(result.exception, InputError), result.output
    assert "sampler 'msa': lambda_u=0 is not allowed; expected a finite number > 0" in str(result.exception)
    assert not out.exists()


def test_the_sample_command_refuses_them_naming_the_key(tmp_path):
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)
    result = runner.invoke(
        app,
        [
            "sample",
            "--poses",
            str(poses),
            "--sampler",
            "spaciousness",
            "-p",
            "smoothing=1",
            "--out",
            str(tmp_path / "out"),
            "--quiet",
        ],
    )
    assert isinstance(result.exception, InputError)
    assert str(result.exception) == (
        "sampler 'spaciousness': smoothing=1 is not allowed; expected a finite number >= 0 and < 1"
    )


def test_the_parameters_are_a_read_only_mapping_of_what_was_given():
    params = check_sampler_params("msa", {"lambda_u": 5, "window": 8})
    assert isinstance(params, SamplerParams) and list(params) == ["lambda_u", "window"] and len(params) == 2
    assert dict(params) == {"lambda_u": 5, "window": 8} and params["window"] == 8 and "alpha" not in params
    assert yaml.safe_load(yaml.safe_dump(dict(params))) == {"lambda_u": 5, "window": 8}
    with pytest.raises(ValueError, match="frozen"):
        params.window = 9


def test_the_msa_page_lists_every_sampler_parameter_with_its_default():
    from pathlib import Path

    text = (Path(__file__).parents[1] / "docs" / "msa.md").read_text()
    documented = {(s, k): d for s, k, d in re.findall(r"^\| ([a-z ]+) \| `(\w+)` \| (\S+) \|", text, re.M)}
    shown = lambda value: str(value).lower() if isinstance(value, bool) else str(value)  # noqa: E731
    wanted = {("every one", k): shown(SamplerParams.model_fields[k].default) for k in ("min_motion", "min_rotation")}
    for name, cls in SAMPLERS.items():
        wanted |= {(name, k): shown(v) for k, v in cls.Params.defaults().items() if ("every one", k) not in wanted}
    assert documented == wanted
