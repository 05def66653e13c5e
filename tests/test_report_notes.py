"""Experiment reports and their inputs: every n/a with its reason (failed cells too), user folders under cells/
are no cells, one-line YAML errors, each finished cell read once on a resume, and per-run reports naming the
scans read."""

from __future__ import annotations

import csv
import io
import json
import shutil
from dataclasses import replace
from pathlib import Path

import pytest
from helpers.metrics import stored_metrics
from test_experiments import TINY, _fake_experiment, finished_experiment
from typer.testing import CliRunner

import msa_slam
from msa_slam.cli import app
from msa_slam.datasets.options import SourceOptions
from msa_slam.errors import InputError
from msa_slam.evaluation.run_metrics import BATCH_UNTIMED
from msa_slam.experiments import folder as folder_module
from msa_slam.experiments import load_grid, parse_grid, run_grid, write_report
from msa_slam.experiments.folder import grid_cells
from msa_slam.experiments.identity import cell_identities, outdated_cells
from msa_slam.experiments.runner import GridRun, _record
from msa_slam.reporting.sequence_text import scans_read

PR_REASON = "no keyframe had an older keyframe to query"


def _metrics(method: str, seed: int, batch: bool) -> dict:
    """A finished cell's metrics.json as the pipelines write it (batch: no per-frame timing); `msa` has no
    PR curve on seed 1."""
    no_pr = method == "msa" and seed == 1
    m = stored_metrics("batch.json" if batch else "online.json")
    full = m["full_rate"]
    full["before"].update(ate_translation_m=2.0, rpe_kitti_translation_pct=1.0)
    full["after"].update(ate_translation_m=1.0 + seed / 10, rpe_kitti_translation_pct=0.5, rpe_10m_translation_m=0.1)
    full["improvement_pct"] = {"translation": 50.0 - 5 * seed, "rotation": 10.0 + seed}
    m["before"]["ate_translation_m"], m["after"]["ate_translation_m"] = 2.0, 1.0
    m.update(
        frames=100,
        keyframes=50,
        candidates=4,
        verified=3,
        false_loops=0,
        improvement_pct={"translation": 50.0, "rotation": 10.0},
        pr_auc=None if no_pr else 0.9 - seed / 100,
        f1_max=None if no_pr else 0.8 + seed / 100,
        unavailable={"pr": PR_REASON} if no_pr else {},
        peak_rss_bytes=2**20,
        rss_growth_bytes=3 * 2**20,
        msa_slam_version=msa_slam.__version__,
    )
    m["memory_bytes"]["total"], m["time_s"]["backend_total"] = 4000 if method == "all" else 1000, 1.0
    rejected = {**dict.fromkeys(m["loop_accounting"]["rejected"], 0), "sparse": 1, "drift": seed}
    m["loop_accounting"]["rejected"] = m["loop_closing"]["rejected"] = rejected
    if not batch:
        m.update(fps=50.0, backend_fps=60.0)
        m["latency_ms"]["backend"]["p99"] = 12.0
    return m


def _experiment(root: Path, grid_data: dict) -> list:
    return finished_experiment(
        root, grid_data, lambda cell: _metrics(cell.method, cell.seed, grid_data.get("pipeline") == "batch")
    )


BATCH = {"name": "b", "pipeline": "batch", "datasets": ["sim:test"], "samplers": ["all", "msa"]}
SEEDS = {**TINY, "samplers": ["all", "msa"], "seeds": [0, 1, 2]}


def test_batch_grid_says_why_frames_per_second_and_p99_are_na(tmp_path):
    _experiment(tmp_path, BATCH)
    write_report(tmp_path)
    table = (tmp_path / "results.md").read_text()
    assert "| n/a | n/a |" in table  # frames/s and back-end p99 of a batch cell
    assert f"- frames/s, back-end p99 n/a (every method): {BATCH_UNTIMED}" in table
    rows = list(csv.DictReader(io.StringIO((tmp_path / "results.csv").read_text())))
    assert all(
        json.loads(r["unavailable"]) == dict.fromkeys(("backend_fps", "backend_p99_ms", "fps"), BATCH_UNTIMED)
        for r in rows
    )


def test_spread_table_has_rss_growth_and_rejected_and_reasons_for_its_na(tmp_path):
    _experiment(tmp_path, SEEDS)
    write_report(tmp_path)
    table = (tmp_path / "results.md").read_text()
    spread = table.split("Spread over seeds:")[1]
    means = next(line for line in spread.splitlines() if line.startswith("| msa | "))
    cells = [c.strip() for c in means.strip("|").split("|")]
    header = next(line for line in spread.splitlines() if line.startswith("| method | "))
    column = dict(zip([c.strip() for c in header.strip("|").split("|")], cells))
    assert column["RSS growth [MiB]"] == "3.00 ± 0.00" and column["rejected"] == "2.0 ± 1.0"  # were n/a
    # msa has no PR curve on seed 1: its means are over seeds 0 and 2, and the notes say why seed 1 is n/a
    assert column["PR-AUC"] == "0.890 ± 0.014"
    assert f"- PR-AUC, F1-max n/a (msa on seed(s) 1): {PR_REASON}" in table
    assert "a mean leaves out the seeds where its value is n/a" in table
    assert "n/a: a value is n/a on seed(s) 1 (that seed's notes say why)" in table  # the paired test


def test_every_na_of_an_experiment_report_has_a_note(tmp_path):
    _experiment(tmp_path, {**BATCH, "pipeline": "batch", "datasets": ["sim:test,seed={seed}"], "seeds": [0, 1]})
    write_report(tmp_path)
    table = (tmp_path / "results.md").read_text()
    assert "n/a" in table.split("Notes (n/a values")[0]
    notes = table.split("Notes (n/a values")[1]
    assert "frames/s, back-end p99 n/a (every method and seed)" in notes
    assert f"PR-AUC, F1-max n/a (msa on seed(s) 1): {PR_REASON}" in notes


def _fail(root: Path, cell, error: Exception) -> None:
    """Make a finished cell one that failed with `error`, its traceback recorded as the runner records it."""
    shutil.rmtree(root / "cells" / cell.id)
    try:
        raise error
    except Exception as exc:
        _record(GridRun(root), cell, exc)


def test_a_method_whose_cells_failed_has_an_na_row_and_a_note_saying_why(tmp_path):
    cells = _experiment(tmp_path, SEEDS)
    kept = "sampler 'msa' kept 1 keyframes of 27 frames; the evaluation needs at least 3"
    for cell in cells:
        if cell.method == "msa":
            _fail(tmp_path, cell, InputError(kept))
        elif cell.seed == 2:
            _fail(tmp_path, cell, RuntimeError("degenerate scan statistics\n  on every frame"))
    write_report(tmp_path)
    table = (tmp_path / "results.md").read_text()
    row = next(line for line in table.splitlines() if line.startswith("| msa |"))
    assert {c.strip() for c in row.strip("|").split("|")[1:]} == {"n/a"}
    notes = table.split("Notes (n/a values")[1].splitlines()
    assert (
        f"- every value n/a (msa): the cell failed with InputError: {kept} (traceback in errors/<cell id>.txt)" in notes
    )
    assert (
        "- every value n/a (all on seed(s) 2): the cell failed with RuntimeError: degenerate scan statistics "
        "(traceback in errors/<cell id>.txt)"
    ) in notes  # a message's first line
    assert "2 of 6 cell(s) finished, 4 failed" in (tmp_path / "report.md").read_text()
    assert len((tmp_path / "results.csv").read_text().splitlines()) == 1 + 2  # finished cells only


def test_a_user_folder_under_cells_is_no_stale_cell(tmp_path):
    _fake_experiment(tmp_path, TINY, {"all": 4000, "const-2m": 1000}, {"all": 0.5, "const-2m": 0.7})
    mine = tmp_path / "cells" / "mystuff"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    _, cells = grid_cells(tmp_path)
    assert folder_module.stale_cells(tmp_path, cells) == []
    old = tmp_path / "cells" / "sim_test-sc-all-s0-0123456789"  # an earlier grid's cell: still stale
    old.mkdir()
    (old / "cell.json").write_text("{}")
    assert folder_module.stale_cells(tmp_path, cells) == [old.name]
    result = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "mystuff" not in result.output and "mystuff" not in (tmp_path / "report.md").read_text()
    assert (mine / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize(
    "text, where",
    [
        (
            "name: t\ndatasets: [a, b\nsamplers: [all]\n",
            "not valid YAML at line 3, column 9: expected ',' or ']', but got ':' (while parsing a flow sequence started "
            "at line 2, column 11)",
        ),
        ("name: t: u\n", "not valid YAML at line 1, column 8: mapping values are not allowed here"),
    ],
)
def test_invalid_grid_yaml_is_one_line_naming_line_and_column(tmp_path, text, where):
    path = tmp_path / "g.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as error:
        load_grid(path)
    assert str(error.value) == f"{path}: {where}"
    result = CliRunner().invoke(app, ["experiment", str(path), "--out", str(tmp_path / "o")])
    assert result.exit_code != 0 and str(result.exception) == f"{path}: {where}"
    assert not (tmp_path / "o").exists()


def test_a_damaged_grid_yaml_of_a_results_folder_is_one_line(tmp_path):
    _fake_experiment(tmp_path, TINY, {"all": 4000, "const-2m": 1000}, {"all": 0.5, "const-2m": 0.7})
    (tmp_path / "grid.yaml").write_text("name: [t\n")
    with pytest.raises(InputError) as error:
        grid_cells(tmp_path)
    assert "\n" not in str(error.value) and "grid.yaml: not valid YAML at line 2, column 1" in str(error.value)
    (tmp_path / "grid.yaml").write_bytes(b"\xff\xfename: t\n")
    with pytest.raises(InputError, match=r"grid.yaml: not UTF-8 text \(byte 0"):
        grid_cells(tmp_path)


def test_a_resume_reads_each_finished_cell_once(tmp_path, monkeypatch):
    cells = _fake_experiment(tmp_path, TINY, {"all": 4000, "const-2m": 1000}, {"all": 0.5, "const-2m": 0.7})
    reads: list[str] = []
    real = folder_module.read_cell

    def counted(folder: Path):
        reads.append(folder.name)
        return real(folder)

    monkeypatch.setattr(folder_module, "read_cell", counted)
    run = run_grid(parse_grid(TINY), tmp_path)
    assert sorted(run.skipped) == sorted(c.id for c in cells) and not run.ran
    assert sorted(reads) == sorted(c.id for c in cells)  # the version check's reading serves the report
    assert "2 of 2 cell(s) finished" in (tmp_path / "report.md").read_text()


def test_outdated_cells_uses_what_was_read(tmp_path):
    cells = _fake_experiment(tmp_path, TINY, {"all": 4000, "const-2m": 1000}, {"all": 0.5, "const-2m": 0.7})
    finished = folder_module.finished_cells(tmp_path, cells)
    assert set(finished) == {c.id for c in cells}
    identities = cell_identities(cells)
    assert outdated_cells(finished, identities) == {}
    cell = finished[cells[0].id]
    assert cell.info.identity is not None
    identity = {**cell.info.identity, "data": "0" * 24}
    finished[cells[0].id] = replace(cell, info=replace(cell.info, identity=identity))
    assert outdated_cells(finished, identities) == {
        cells[0].id: f"cell {cells[0].id}: its data changed since it ran; rerun"
    }


@pytest.mark.parametrize(
    "options, said",
    [
        ({}, "every scan"),
        ({"frames": 200}, "at most 200 scans (-n 200)"),
        (
            {"first": 10, "jump": 2, "frames": 50},
            "from scan 10 (--first 10), one scan in 2 (--jump 2), at most 50 scans (-n 50)",
        ),
    ],
)
def test_scans_read_names_the_options_that_chose_them(options, said):
    assert scans_read(SourceOptions(**options)) == said


def test_run_report_names_the_sequence_readably_and_the_scans_read(sequence, odometry_file, cache_dir, tmp_path):
    from msa_slam.pipeline import make_config, run
    from msa_slam.reporting.results import write_run
    from msa_slam.viz.labels import display_name

    cfg = make_config(
        dataset=str(sequence),
        odometry=str(odometry_file),
        cache_dir=str(cache_dir),
        sampler="constant",
        sampler_params={"distance": 3.0},
        source={"frames": 80},
    )
    result = run(cfg)
    report = write_run(lambda: result, tmp_path / "out").read_text()
    title = report.splitlines()[0]
    assert display_name(sequence.name) != sequence.name  # the simulated sequence's cache name has a hash
    assert title == f"# {cfg.name} on {display_name(sequence.name)} ({cfg.mode} loops)"
    assert f"Dataset `{sequence}` (sequence {sequence.name}), at most 80 scans (-n 80): 80 frames -> " in report


def test_invalid_config_yaml_is_one_line_naming_line_and_column(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("sampler: msa\nsampler_params: {window: 8\n")
    result = CliRunner().invoke(app, ["run", "--config", str(path), "--out", str(tmp_path / "o"), "--quiet"])
    assert isinstance(result.exception, InputError)
    assert str(result.exception).startswith(f"{path}: not valid YAML at line 3, column 1: ")
    assert "\n" not in str(result.exception) and not (tmp_path / "o").exists()
