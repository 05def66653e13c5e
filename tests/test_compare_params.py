"""`compare` gives the user's sampler parameters (-p window=8, -p sampler.lambda_u=5, a config file's) to MSA,
the method under study, and keeps the baselines at the paper's settings; a parameter MSA does not take is
refused (QA finding H1: they used to be dropped silently)."""

from __future__ import annotations

import pytest
from helpers.cli import main_in_process, on_scans
from helpers.streams import write_scans

from msa_slam.errors import InputError
from msa_slam.experiments.compare import PAPER_METHODS, check_compare_sampler, method_configs
from msa_slam.pipeline.config import apply_params, make_config


def test_sampler_parameters_reach_msa_only():
    base = apply_params(make_config(dataset="sim:test"), ["window=8", "sampler.lambda_u=5"])
    configs = {c.name: c for c in method_configs(base)}
    assert configs["msa"].sampler == "msa" and configs["msa"].sampler_params == {"window": 8, "lambda_u": 5}
    assert {name: (c.sampler, c.sampler_params) for name, c in configs.items() if name != "msa"} == {
        label: (sampler, params) for label, sampler, params in PAPER_METHODS if label != "msa"
    }


def test_a_method_keeps_its_own_msa_parameters_over_the_users():
    base = make_config(dataset="sim:test", sampler_params={"window": 8, "lambda_u": 5})
    (study,) = method_configs(base, (("msa-w12", "msa", {"window": 12}),))
    assert study.sampler_params == {"window": 12, "lambda_u": 5}


@pytest.mark.parametrize(
    "param, message",
    [
        ("distance=2", r"^--param 'distance': not a config key .*a parameter of sampler 'msa' \(window, "),
        ("sampler.distance=2", r"^config: sampler 'msa': unknown parameter\(s\) distance; it takes: window=10"),
    ],
)
def test_a_parameter_msa_does_not_take_is_refused_by_the_existing_checks(param, message):
    with pytest.raises(InputError, match=message):
        apply_params(make_config(dataset="sim:test"), [param])


def test_another_samplers_parameters_are_refused_naming_where_they_go():
    base = apply_params(make_config(dataset="sim:test"), ["sampler=constant", "distance=2"])  # fine for run
    with pytest.raises(InputError) as err:
        check_compare_sampler(base)
    assert str(err.value) == (
        "compare: the sampler parameters go to msa (the baselines keep the paper's settings); "
        "distance=2 are for sampler 'constant': drop them, or give them to "
        "`msa-slam run -p sampler=constant`"
    )
    check_compare_sampler(make_config(dataset="sim:test", sampler="constant"))  # no parameters: nothing dropped
    check_compare_sampler(apply_params(make_config(dataset="sim:test"), ["window=8"]))
    # the library's run_compare takes any base: another sampler's parameters stay with that sampler
    configs = {c.name: c for c in method_configs(base)}
    assert configs["msa"].sampler_params == {} and configs["constant-2m"].sampler_params == {"distance": 2.0}


def test_compare_checks_the_window_given_with_p(tmp_path, monkeypatch, capsys):
    scans = write_scans(tmp_path / "scans", 4)
    args = on_scans("compare", scans, tmp_path, "-p", "flush=false", "-p", "window=6")
    result = main_in_process(monkeypatch, capsys, *args)
    assert result.returncode == 2, result.stderr
    assert result.stderr.splitlines()[-1] == (
        "error: sampler 'msa': window=6 is longer than the 4 frames read, so it never fills and only frame 0 becomes "
        "a keyframe (flush is off); the evaluation needs at least 3: use a window of at most 4 frames "
        "(-p window=4) or -p flush=true"
    )
    assert not (tmp_path / "out").exists()
