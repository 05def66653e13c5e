"""Grid checks made before any cell runs: a cell's config agrees with its label, seeds are real and distinct,
datasets and the scheduler address exist, and a resume never mixes cells of other code."""

from __future__ import annotations

import json

import pytest
import yaml
from helpers.cli import main_in_process, run_cli
from test_experiments import TINY, _fake_experiment

import msa_slam
from msa_slam.errors import InputError
from msa_slam.experiments import expand, parse_grid, run_grid

MSA_SWEEP = {"sampler": "msa", "sweep": {"window": [6, 12]}}


@pytest.mark.parametrize(
    "change, message",
    [
        (
            {"samplers": [MSA_SWEEP], "parameters": {"window": [9]}},
            "g.yaml: 'window' is set both in `parameters` and in the `sweep` of method 'msa'; set it in one place",
        ),
        (
            {"samplers": [MSA_SWEEP], "parameters": {"sampler.window": [9]}},
            "g.yaml: 'sampler.window' is set both in `parameters` and in the `sweep` of method 'msa'; set it in one place",
        ),
        (
            {"samplers": [{"label": "a10", "sampler": "msa", "params": {"alpha": 10}}], "parameters": {"alpha": [2]}},
            "g.yaml: 'alpha' is set both in `parameters` and in the `params` of method 'a10'; set it in one place",
        ),
        (
            {"parameters": {"sampler": ["msa"]}},
            "g.yaml: parameters: 'sampler' is set by the grid per cell; list it under `samplers:` instead",
        ),
        (
            {"base": {**TINY["base"], "sampler": "constant"}},
            "g.yaml: base: 'sampler' is set by the grid per cell; list it under `samplers:` instead",
        ),
        (
            {"base": {**TINY["base"], "dataset": "sim:test"}},
            "g.yaml: base: 'dataset' is set by the grid per cell; list it under `datasets:` instead",
        ),
        (
            {"base": {**TINY["base"], "seed": 7}},
            "g.yaml: base: 'seed' is set by the grid per cell; list it under `seeds:` instead",
        ),
        (
            {"base": {**TINY["base"], "sampler_params": {"windw": 5}}},
            "g.yaml: base: sampler_params windw: no method's sampler takes it (samplers: all, constant)",
        ),
        (
            {"pipeline": "batch", "datasets": ["sim:test"], "seeds": [0, 1], "base": {}},
            "g.yaml: seeds [0, 1] but dataset 'sim:test' has no {seed}: every seed would run the same cell (a batch run "
            "takes its seed from the dataset)",
        ),
        ({"seeds": [True]}, "g.yaml: seeds.0: Input should be a valid integer"),
        ({"seeds": [-1]}, "g.yaml: seeds.0: Input should be greater than or equal to 0"),
        ({"samplers": ["msa", "msa"]}, "g.yaml: method labels repeat (msa); give each a label"),
    ],
)
def test_grid_refuses_what_its_labels_would_misreport(change, message):
    with pytest.raises(InputError) as error:
        parse_grid({**TINY, **change}, "g.yaml")
    assert str(error.value) == message


def test_batch_seeds_with_seed_in_the_dataset_are_distinct_cells():
    cells = expand(
        parse_grid({**TINY, "pipeline": "batch", "datasets": ["sim:test,seed={seed}"], "seeds": [0, 1], "base": {}})
    )
    assert [c.config["dataset"] for c in cells] == ["sim:test,seed=0", "sim:test,seed=1"] * 2


def test_base_sampler_params_apply_below_the_methods_own_and_swept_values(tmp_path):
    grid = parse_grid(
        {
            **TINY,
            "samplers": ["all", {"label": "a10", "sampler": "msa", "params": {"alpha": 10}}, MSA_SWEEP],
            "base": {**TINY["base"], "sampler_params": {"window": 5, "alpha": 3}},
        }
    )
    assert {c.method: c.config["sampler_params"] for c in expand(grid)} == {
        "all": {},
        "a10": {"window": 5, "alpha": 10},
        "msa window=6": {"window": 6, "alpha": 3},
        "msa window=12": {"window": 12, "alpha": 3},
    }
    ran = parse_grid({**TINY, "samplers": ["constant"], "base": {**TINY["base"], "sampler_params": {"distance": 2.0}}})
    run = run_grid(ran, tmp_path)
    assert not run.failed
    config = yaml.safe_load((tmp_path / "cells" / run.ran[0] / "config.yaml").read_text())
    assert config["sampler"] == "constant" and config["sampler_params"] == {"distance": 2.0}


@pytest.mark.parametrize(
    "dataset, message",
    [
        ("sim:nosuch", "dataset 'sim:nosuch': unknown simulated sequence 'nosuch'; choose one of demo, test, kitti-00"),
        ("/nonexistent/folder", "dataset '/nonexistent/folder': not found (give a sequence folder, a bag or sim:NAME)"),
        (
            "live:nosuch,stride=2",
            "dataset 'live:nosuch,stride=2': unknown simulated sequence 'nosuch'; choose one of demo, test, kitti-00",
        ),
    ],
)
def test_unknown_dataset_is_one_line_before_the_result_folder(tmp_path, monkeypatch, capsys, dataset, message):
    grid_file = tmp_path / "g.yaml"
    grid_file.write_text(yaml.safe_dump({**TINY, "datasets": ["live:figure-eight", dataset]}))
    result = main_in_process(monkeypatch, capsys, "experiment", str(grid_file), "--out", str(tmp_path / "o"), "--quiet")
    assert result.returncode == 2
    assert result.stderr.startswith(f"error: {grid_file}: {message}") and len(result.stderr.splitlines()) == 1
    assert not (tmp_path / "o").exists()


RECORDINGS_ONLY = (
    "applies to recordings; a sim: dataset is one simulated sequence in KITTI's layout (choose its "
    "frames with --first/--jump/-n or start=, end=, stride= in the spec)"
)


@pytest.mark.parametrize(
    "base, message",
    [
        ({"source": {"first": 5000}}, "dataset 'sim:test': --first 5000 is beyond its 214 scans (0..213)"),
        ({"source": {"first": 10, "frames": 2}}, "dataset 'sim:test': 2 scans selected; a run needs at least 3"),
        ({"source": {"topic": "/points"}}, f"dataset 'sim:test': --topic {RECORDINGS_ONLY}"),
        ({"dataset_kind": "bag"}, f"dataset 'sim:test': --loader {RECORDINGS_ONLY}"),
    ],
)
def test_a_simulated_cell_that_cannot_run_is_one_line_before_the_result_folder(
    tmp_path, monkeypatch, capsys, base, message
):
    """A selection beyond the simulated sequence, or an option only recordings have, is refused before anything
    is simulated and before the result folder is made."""
    monkeypatch.setenv("MSA_SLAM_CACHE", str(tmp_path / "cache"))
    grid_file = tmp_path / "g.yaml"
    grid_file.write_text(yaml.safe_dump({**TINY, "datasets": ["sim:test"], "base": {**TINY["base"], **base}}))
    result = main_in_process(monkeypatch, capsys, "experiment", str(grid_file), "--out", str(tmp_path / "o"), "--quiet")
    assert result.returncode == 2
    assert result.stderr.strip() == f"error: {grid_file}: {message}"
    assert not (tmp_path / "o").exists() and not (tmp_path / "cache").exists()  # nothing simulated


def test_malformed_scheduler_is_one_line_before_the_result_folder(tmp_path):
    """In a fresh process, as a user runs it: the experiment command's refusal is this one line there too."""
    result = run_cli("experiment", "tiny", "--scheduler", "notaurl", "--out", str(tmp_path / "o"), "--quiet")
    assert result.returncode == 2
    assert result.stderr.strip() == (
        "error: --scheduler 'notaurl': missing port number in address 'notaurl'; give the address as tcp://host:port"
    )
    assert not (tmp_path / "o").exists()


def test_resume_reruns_a_cell_of_other_code_instead_of_mixing_it_in(tmp_path, caplog):
    """A cell run by another msa-slam (another version, or edited code: another fingerprint) is rerun, saying
    so, rather than refused (the version refusal gave no way to resume) or reported beside the others."""
    cells = _fake_experiment(tmp_path, TINY, {"all": 4000, "const-2m": 1000}, {"all": 0.5, "const-2m": 0.7})
    cell_json = tmp_path / "cells" / cells[1].id / "cell.json"
    info = json.loads(cell_json.read_text())
    cell_json.write_text(json.dumps({**info, "identity": {**info["identity"], "code": "0" * 24}}))
    run = run_grid(parse_grid(TINY), tmp_path)
    line = f"cell {cells[1].id}: its code changed since it ran; rerun"
    assert run.rerun == {cells[1].id: line} and run.ran == [cells[1].id] and run.skipped == [cells[0].id]
    assert f"experiment: {line}" in caplog.text and f"- {line}" in (tmp_path / "report.md").read_text()
    assert json.loads(cell_json.read_text())["identity"] == info["identity"]
    assert json.loads((cell_json.parent / "metrics.json").read_text())["msa_slam_version"] == msa_slam.__version__
