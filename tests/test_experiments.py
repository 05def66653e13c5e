"""Experiment grids: validation errors, cell expansion, resume after a crash, Dask execution, reports."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
from helpers.cli import main_in_process
from helpers.metrics import stored_metrics
from typer.testing import CliRunner

import msa_slam
from msa_slam.cli import app
from msa_slam.errors import InputError
from msa_slam.experiments import (
    expand,
    is_finished,
    load_cells,
    load_grid,
    make_rows,
    parse_grid,
    run_cell,
    run_grid,
    write_report,
)
from msa_slam.experiments.cell_info import CellRecord
from msa_slam.experiments.folder import write_grid
from msa_slam.experiments.grid import Cell
from msa_slam.experiments.identity import cell_identities
from msa_slam.io import staging
from msa_slam.io.outputs import OutputError, open_result_folder, write_marker

TINY = {
    "name": "t",
    "datasets": ["live:figure-eight,stride=8,azimuth_steps=180"],  # 54 scans, loops at its crossing and close
    "samplers": ["all", {"label": "const-2m", "sampler": "constant", "params": {"distance": 2.0}}],
    "base": {
        "odometry": "gt-noise",
        "odometry_params": {"translation_noise": 0.02, "rotation_noise_deg": 0.1},
        "min_frame_gap": 20,
    },
}

# One cell that fails fast (its single keyframe is too few), after a real start.
TOO_SPARSE = {**TINY, "samplers": [{"label": "too-sparse", "sampler": "constant", "params": {"distance": 1000.0}}]}


@pytest.mark.parametrize(
    "change, message",
    [
        ({"dataset": ["x"]}, r"unknown key 'dataset'; valid keys: name, pipeline, datasets, descriptors, samplers"),
        (
            {"samplers": [{"sampler": "msa", "parms": {}}]},
            r"g.yaml: unknown key 'samplers.0.parms'; valid keys: sampler, label",
        ),
        (
            {"samplers": [{"sampler": "msa", "params": {"alpha_": 2}}]},
            r"unknown parameter\(s\) alpha_; it takes: window",
        ),
        ({"samplers": ["nope"]}, "unknown sampler 'nope'"),
        (
            {"base": {"odometry": "gt-noise", "colud_store": "disk"}},
            "unknown key 'colud_store'; valid keys: .*cloud_store",
        ),
        ({"parameters": {"verifier.gate": [1]}}, "unknown key 'verifier.gate'"),
        ({"pipeline": "offline"}, "pipeline: Input should be 'online' or 'batch'"),
        ({"seeds": []}, "seeds: List should have at least 1 item"),
        ({"samplers": ["msa", "msa"]}, "method labels repeat"),
        ({"parameters": {"similarity_threshold": []}}, "parameters 'similarity_threshold' has no values"),
        ({"reference": "msa"}, "reference 'msa' is not a method of the grid; methods: all, const-2m"),
    ],
)
def test_grid_validation_errors(change, message):
    with pytest.raises(InputError, match=message):
        parse_grid({**TINY, **change}, "g.yaml")


def test_grid_expansion_sweeps_parameters_and_stable_ids():
    grid = parse_grid(
        {
            **TINY,
            "samplers": ["all", {"sampler": "msa", "params": {"lambda_u": 5.0}, "sweep": {"lambda_l": [0.0, 1.0]}}],
            "parameters": {"similarity_threshold": [0.7, 0.8]},
            "seeds": [0, 1],
        }
    )
    cells = expand(grid)
    assert len(cells) == 3 * 2 * 2
    assert {c.method for c in cells} == {"all", "msa lambda_l=0.0", "msa lambda_l=1.0"}
    swept = next(c for c in cells if c.method == "msa lambda_l=1.0")
    assert swept.config["sampler_params"] == {"lambda_u": 5.0, "lambda_l": 1.0} and swept.swept == {"lambda_l": 1.0}
    assert {c.config["similarity_threshold"] for c in cells} == {0.7, 0.8}
    assert {c.config["seed"] for c in cells} == {0, 1}
    assert [c.id for c in expand(grid)] == [c.id for c in cells] and len({c.id for c in cells}) == len(cells)


def test_shipped_presets_validate():
    counts = {name: len(expand(load_grid(name))) for name in ("table2", "ablation", "distance_bounds", "tiny")}
    assert counts == {"table2": 24, "ablation": 30, "distance_bounds": 26, "tiny": 2}
    with pytest.raises(
        InputError,
        match="grid file not found .*presets: ablation, distance_bounds, "
        "paper-ablation, paper-bounds, paper-table1, paper-table2, table2, tiny",
    ):
        load_grid("nope")


def test_resume_skips_finished_cells_and_clears_half_written_ones(tmp_path):
    grid = parse_grid(TINY)
    first, second = expand(grid)
    write_marker(tmp_path, "experiment")
    run_cell(recorded_info(first), first.config, str(tmp_path))  # finished before the "crash"
    finished = tmp_path / "cells" / first.id / "metrics.json"
    stamp = finished.stat().st_mtime_ns
    partial = tmp_path / "cells" / f".{second.id}.partial-abc123"  # killed while writing
    partial.mkdir()
    (partial / "metrics.json").write_text("{")
    (partial / staging.WRITER).write_bytes(staging.stamp())  # its writer's stamp, no longer locked: the writer is gone
    assert is_finished(tmp_path, first) and not is_finished(tmp_path, second)

    run = run_grid(grid, tmp_path)
    assert run.skipped == [first.id] and run.ran == [second.id] and not run.failed
    assert finished.stat().st_mtime_ns == stamp  # not recomputed
    assert not partial.exists()
    rows = (tmp_path / "results.csv").read_text().splitlines()
    assert len(rows) == 3
    table = (tmp_path / "results.md").read_text()
    assert "| all | 54 |" in table and "| const-2m |" in table
    assert (tmp_path / "figures" / "ate_difference.png").is_file()


def test_failing_cell_is_recorded_and_retried(tmp_path):
    grid = parse_grid(TOO_SPARSE)
    run = run_grid(grid, tmp_path)
    (cell,) = expand(grid)
    assert list(run.failed) == [cell.id] and "kept only 1 of" in run.failed[cell.id]
    assert (tmp_path / "errors" / f"{cell.id}.txt").is_file() and not is_finished(tmp_path, cell)


def test_dask_local_cluster_runs_two_cells(tmp_path):
    distributed = pytest.importorskip("distributed")
    with (
        distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=":0") as cluster,
        distributed.Client(cluster) as client,
    ):
        run = run_grid(parse_grid(TINY), tmp_path, client=client)
    assert sorted(run.ran) == sorted(c.id for c in expand(parse_grid(TINY))) and not run.failed
    assert len((tmp_path / "results.csv").read_text().splitlines()) == 3


SWEEP = {**TINY, "samplers": ["all", {"sampler": "msa", "sweep": {"lambda_l": [0.0, 1.0]}}]}


def recorded_info(cell: Cell) -> CellRecord:
    """The record of `cell` as run_grid writes it now (with the identity of its data and code)."""
    return CellRecord.of(cell, cell_identities([cell])[cell.id])


def finished_experiment(root: Path, grid_data: dict, metrics_of: Callable[[Cell], dict]) -> list:
    """An experiment folder whose grid.yaml is `grid_data` and whose cells are finished, on the current data and
    code, with the metrics `metrics_of(cell)`; returns the cells."""
    grid = parse_grid(grid_data)
    root.mkdir(exist_ok=True)
    write_grid(root, grid)
    cells = expand(grid)
    for cell in cells:
        folder = root / "cells" / cell.id
        folder.mkdir(parents=True)
        (folder / "cell.json").write_text(json.dumps(recorded_info(cell).to_json()))
        (folder / "metrics.json").write_text(json.dumps(metrics_of(cell)))
    write_marker(root, "experiment")  # last: it lists the files above as msa-slam's
    return cells


def _fake_experiment(root: Path, grid_data: dict, memory: dict[str, int], ate_after: dict[str, float]) -> list:
    """finished_experiment with made-up metrics per method (`memory` bytes, `ate_after` metres)."""

    def metrics(cell: Cell) -> dict:
        ate = ate_after[cell.method]
        m = stored_metrics(f"{cell.pipeline}.json")
        improvement = {"translation": 100 * (2.0 - ate) / 2.0, "rotation": 10.0}
        for block in (m, m["full_rate"]):
            block["before"]["ate_translation_m"], block["after"]["ate_translation_m"] = 2.0, ate
            block["improvement_pct"] = dict(improvement)
        m.update(
            frames=100,
            keyframes=50,
            candidates=4,
            verified=3,
            false_loops=0,
            pr_auc=0.9,
            f1_max=0.8,
            peak_rss_bytes=2**20,
            msa_slam_version=msa_slam.__version__,
        )
        m["memory_bytes"]["total"], m["time_s"]["backend_total"] = memory[cell.method], 1.0
        if cell.pipeline == "online":
            m.update(fps=50.0, backend_fps=60.0)
            m["latency_ms"]["backend"]["p99"] = 12.0
        return m

    return finished_experiment(root, grid_data, metrics)


def _sweep_experiment(root: Path) -> list:
    return _fake_experiment(
        root,
        SWEEP,
        {"all": 4000, "msa lambda_l=0.0": 2000, "msa lambda_l=1.0": 1000},
        {"all": 0.5, "msa lambda_l=0.0": 0.6, "msa lambda_l=1.0": 0.9},
    )


def test_report_relative_memory_ate_difference_and_sweep_figure(tmp_path):
    _sweep_experiment(tmp_path)
    (tmp_path / "cells" / ".x.partial-1").mkdir()  # ignored
    result = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert result.exit_code == 0, result.output
    rows = {r.method: r for r in make_rows(load_cells(tmp_path))}
    assert rows["msa lambda_l=0.0"].value("memory_vs_reference_pct") == pytest.approx(50.0)
    assert rows["msa lambda_l=1.0"].value("memory_vs_reference_pct") == pytest.approx(25.0)
    for name in ("ate_difference.png", "distance_bounds.png"):
        assert (tmp_path / "figures" / name).is_file()
    assert "| msa lambda_l=1.0 | 50 | 55.0 % |" in (tmp_path / "results.md").read_text()
    assert (
        "before of the full-rate trajectory (every frame, posed from the keyframe before it; SE(3)-aligned)"
        in (tmp_path / "report.md").read_text()
    )  # what the "(full rate)" columns show


def test_report_reference_must_be_a_method_of_the_experiment(tmp_path):
    _sweep_experiment(tmp_path)
    with pytest.raises(
        InputError,
        match=r"--reference 'foo': not a method of this experiment; available: all, "
        r"msa lambda_l=0.0, msa lambda_l=1.0",
    ):
        write_report(tmp_path, "foo")
    assert not (tmp_path / "report.md").exists()
    rows = {r.method: r for r in make_rows(load_cells(tmp_path), "msa lambda_l=0.0")}
    assert rows["all"].value("memory_vs_reference_pct") == pytest.approx(200.0)


def test_changed_grid_into_same_out_reports_only_its_own_cells(tmp_path):
    old = _fake_experiment(tmp_path, TINY, {"all": 4000, "const-2m": 1000}, {"all": 0.5, "const-2m": 0.7})
    changed = {**TINY, "samplers": ["all"], "base": {**TINY["base"], "min_frame_gap": 25}}
    run = run_grid(parse_grid(changed), tmp_path)
    (new,) = expand(parse_grid(changed))
    assert run.ran == [new.id] and not run.skipped and not run.failed
    assert run.stale == sorted(c.id for c in old)
    assert [c.info.id for c in load_cells(tmp_path)] == [new.id]
    assert len((tmp_path / "results.csv").read_text().splitlines()) == 2
    assert (
        "1 seed(s)" in (tmp_path / "results.md").read_text() and "const-2m" not in (tmp_path / "results.md").read_text()
    )
    report = (tmp_path / "report.md").read_text()
    assert "1 of 1 cell(s) finished" in report
    assert all(c.id in report.split("Stale cells")[1].splitlines()[0] for c in old)
    assert all((tmp_path / "cells" / c.id).is_dir() for c in old)  # kept (ours, but only --overwrite discards)
    result = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert result.exit_code == 0 and "2 stale cell(s) from an earlier grid" in result.output
    assert all(c.id in result.output for c in old)


def test_corrupt_cell_is_rerun_not_dropped(tmp_path):
    grid = {**TINY, "samplers": ["all"]}
    (cell,) = _fake_experiment(tmp_path, grid, {"all": 4000}, {"all": 0.5})
    metrics = tmp_path / "cells" / cell.id / "metrics.json"
    metrics.write_text('{"frames": 10')  # truncated by a full disk or a crash of an older version
    assert not is_finished(tmp_path, cell) and load_cells(tmp_path) == []
    run = run_grid(parse_grid(grid), tmp_path)
    assert run.ran == [cell.id] and not run.skipped
    assert json.loads(metrics.read_text())["frames"] > 10 and is_finished(tmp_path, cell)


def _user_folder(root: Path) -> dict[Path, bytes]:
    (root / "sub").mkdir(parents=True)
    (root / "thesis.tex").write_text("\\chapter{}")
    (root / "sub" / "a.bin").write_bytes(b"\0\1")
    return {p: p.read_bytes() for p in root.rglob("*") if p.is_file()}


def test_output_not_written_by_an_experiment_is_refused_untouched(tmp_path):
    user = tmp_path / "user"
    before = _user_folder(user)
    with pytest.raises(OutputError, match="not a msa-slam result folder"):
        run_grid(parse_grid(TINY), user)
    assert {p: p.read_bytes() for p in user.rglob("*") if p.is_file()} == before
    file = tmp_path / "notes.txt"
    file.write_text("mine")
    with pytest.raises(OutputError, match="is a file"):
        run_grid(parse_grid(TINY), file)
    assert file.read_text() == "mine"
    other = tmp_path / "run"
    other.mkdir()
    write_marker(other, "run")
    (other / "metrics.json").write_text("{}")
    with pytest.raises(OutputError, match="previous msa-slam result; pass --overwrite"):
        run_grid(parse_grid(TINY), other)
    assert sorted(p.name for p in other.iterdir()) == [".msa-slam-result", "metrics.json"]
    result = CliRunner().invoke(app, ["report", str(user)])
    assert isinstance(result.exception, InputError) and "not a msa-slam result folder" in str(result.exception)
    assert {p: p.read_bytes() for p in user.rglob("*") if p.is_file()} == before


def test_second_run_on_a_locked_experiment_refuses(tmp_path):
    out = tmp_path / "exp"
    with open_result_folder(out, kind="experiment", default_parent=tmp_path, resume=True) as folder:
        folder.prepare_in_place()
        with pytest.raises(OutputError, match="another msa-slam run is writing"):
            run_grid(parse_grid(TINY), out)
        assert sorted(p.name for p in out.iterdir()) == [".msa-slam-result"]


def test_overwrite_discards_the_previous_experiment(tmp_path):
    old = _fake_experiment(tmp_path / "exp", TINY, {"all": 4000, "const-2m": 1000}, {"all": 0.5, "const-2m": 0.7})
    run = run_grid(parse_grid(TOO_SPARSE), tmp_path / "exp", overwrite=True)
    assert len(run.failed) == 1 and not run.stale
    assert not any((tmp_path / "exp" / "cells" / c.id).exists() for c in old)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no .exp.old-* or lock left


def test_overwrite_refuses_an_experiment_holding_someone_elses_files(tmp_path):
    _fake_experiment(tmp_path / "exp", TINY, {"all": 4000, "const-2m": 1000}, {"all": 0.5, "const-2m": 0.7})
    (tmp_path / "exp" / "notes.md").write_text("mine")
    assert CliRunner().invoke(app, ["report", str(tmp_path / "exp")]).exit_code == 0  # in place: notes stay not ours
    with pytest.raises(OutputError, match=r"holds files msa-slam did not write \(notes.md\)"):
        run_grid(parse_grid(TOO_SPARSE), tmp_path / "exp", overwrite=True)
    assert (tmp_path / "exp" / "notes.md").read_text() == "mine"


def test_experiment_exit_code_names_failed_cells_and_keeps_their_log(tmp_path, monkeypatch, capsys):
    grid_file = tmp_path / "g.yaml"
    grid_file.write_text(yaml.safe_dump(TOO_SPARSE))
    result = main_in_process(monkeypatch, capsys, "experiment", str(grid_file), "--out", str(tmp_path / "o"), "--quiet")
    cells = expand(load_grid(grid_file))
    assert result.returncode == 1, result.stderr
    failed = [line for line in result.stderr.splitlines() if line.startswith("failed: ")]
    assert [line.split(": ")[1] for line in failed] == [c.id for c in cells]
    assert all("kept only 1 of" in line for line in failed)
    assert all((tmp_path / "o" / "errors" / f"{c.id}.txt").is_file() for c in cells)
    assert result.stdout.strip() == str(tmp_path / "o" / "report.md")
    assert "0 of 1 cell(s) finished, 1 failed" in (tmp_path / "o" / "report.md").read_text()


def test_grid_without_cells_is_an_error_before_any_work(tmp_path):
    grid_file = tmp_path / "g.yaml"
    grid_file.write_text(yaml.safe_dump({**TINY, "parameters": {"similarity_threshold": []}}))
    result = CliRunner().invoke(app, ["experiment", str(grid_file), "--out", str(tmp_path / "o"), "--quiet"])
    assert result.exit_code != 0 and isinstance(result.exception, InputError)
    assert str(result.exception) == (
        f"{grid_file}: parameters: Value error, parameters 'similarity_threshold' "
        "has no values (the grid would have no cells)"
    )
    assert not (tmp_path / "o").exists()


def test_report_and_experiment_cli_errors(tmp_path):
    with pytest.raises(InputError, match="not an experiment results folder"):
        write_report(tmp_path)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**TINY, "sampler": ["all"]}))
    result = CliRunner().invoke(app, ["experiment", str(bad), "--out", str(tmp_path / "o")])
    assert result.exit_code != 0 and "unknown key 'sampler'" in str(result.exception)
    assert not os.path.exists(tmp_path / "o")


def test_report_names_a_cell_whose_files_are_damaged(tmp_path):
    cells = _fake_experiment(tmp_path / "exp", TINY, {"all": 4000, "const-2m": 1000}, {"all": 0.5, "const-2m": 0.7})
    (tmp_path / "exp" / "cells" / cells[1].id / "metrics.json").write_text('{"broken":')
    assert CliRunner().invoke(app, ["report", str(tmp_path / "exp")]).exit_code == 0
    text = (tmp_path / "exp" / "report.md").read_text()
    assert "1 of 2 cell(s) finished" in text
    assert (
        f"Cells left out, their cell.json or metrics.json unreadable (run the experiment again to redo them): "
        f"cells/{cells[1].id}" in text
    )
