"""Experiment grids: validation errors, cell expansion, resume after a crash, Dask execution, reports."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.errors import InputError
from msa_slam.experiments import (expand, is_finished, load_cells, load_grid, make_rows, parse_grid, run_cell,
                                  run_grid, write_report)

TINY = {
    "name": "t",
    "datasets": ["live:figure-eight,stride=4,azimuth_steps=180"],
    "samplers": ["all", {"label": "const-2m", "sampler": "constant", "params": {"distance": 2.0}}],
    "base": {"odometry": "gt-noise", "odometry_params": {"translation_noise": 0.02, "rotation_noise_deg": 0.1},
             "min_frame_gap": 20},
}


@pytest.mark.parametrize("change, message", [
    ({"dataset": ["x"]}, r"unknown key 'dataset'; valid keys: name, pipeline, datasets, descriptors, samplers"),
    ({"samplers": [{"sampler": "msa", "parms": {}}]},
     r"g.yaml: unknown key 'samplers.0.parms'; valid keys: sampler, label"),
    ({"samplers": [{"sampler": "msa", "params": {"alpha_": 2}}]}, r"unknown parameter\(s\) alpha_; it takes: window"),
    ({"samplers": ["nope"]}, "unknown sampler 'nope'"),
    ({"base": {"odometry": "gt-noise", "colud_store": "disk"}}, "unknown key 'colud_store'; valid keys: .*cloud_store"),
    ({"parameters": {"verifier.gate": [1]}}, "unknown key 'verifier.gate'"),
    ({"pipeline": "offline"}, "pipeline: Input should be 'online' or 'batch'"),
    ({"seeds": []}, "seeds: List should have at least 1 item"),
    ({"samplers": ["msa", "msa"]}, "method labels repeat"),
])
def test_grid_validation_errors(change, message):
    with pytest.raises(InputError, match=message):
        parse_grid({**TINY, **change}, "g.yaml")


def test_grid_expansion_sweeps_parameters_and_stable_ids():
    grid = parse_grid({**TINY, "samplers": ["all", {"sampler": "msa", "params": {"lambda_u": 5.0},
                                                    "sweep": {"lambda_l": [0.0, 1.0]}}],
                       "parameters": {"similarity_threshold": [0.7, 0.8]}, "seeds": [0, 1]})
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
    with pytest.raises(InputError, match="grid file not found .*presets: ablation, distance_bounds, table2, tiny"):
        load_grid("nope")


def test_resume_skips_finished_cells_and_clears_half_written_ones(tmp_path):
    grid = parse_grid(TINY)
    first, second = expand(grid)
    run_cell(first.info(), first.config, str(tmp_path))  # finished before the "crash"
    finished = tmp_path / "cells" / first.id / "metrics.json"
    stamp = finished.stat().st_mtime_ns
    partial = tmp_path / "cells" / f".{second.id}.partial-abc123"  # killed while writing
    partial.mkdir()
    (partial / "metrics.json").write_text("{")
    assert is_finished(tmp_path, first) and not is_finished(tmp_path, second)

    run = run_grid(grid, tmp_path)
    assert run.skipped == [first.id] and run.ran == [second.id] and not run.failed
    assert finished.stat().st_mtime_ns == stamp  # not recomputed
    assert not partial.exists()
    rows = (tmp_path / "results.csv").read_text().splitlines()
    assert len(rows) == 3
    table = (tmp_path / "results.md").read_text()
    assert "| all | 107 |" in table and "| const-2m |" in table
    assert (tmp_path / "figures" / "ate_difference.png").is_file()


def test_failing_cell_is_recorded_and_retried(tmp_path):
    grid = parse_grid({**TINY, "samplers": [{"label": "too-sparse", "sampler": "constant",
                                             "params": {"distance": 1000.0}}]})
    run = run_grid(grid, tmp_path)
    (cell,) = expand(grid)
    assert list(run.failed) == [cell.id] and "kept 1 keyframes" in run.failed[cell.id]
    assert (tmp_path / "errors" / f"{cell.id}.txt").is_file() and not is_finished(tmp_path, cell)


def test_dask_local_cluster_runs_two_cells(tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=":0") as cluster, distributed.Client(cluster) as client:
        run = run_grid(parse_grid(TINY), tmp_path, client=client)
    assert sorted(run.ran) == sorted(c.id for c in expand(parse_grid(TINY))) and not run.failed
    assert len((tmp_path / "results.csv").read_text().splitlines()) == 3


def _fake_cell(root: Path, cid: str, method: str, memory: int, ate_after: float, swept: dict) -> None:
    folder = root / "cells" / cid
    folder.mkdir(parents=True)
    info = {"id": cid, "pipeline": "online", "dataset": "d", "descriptor": "sc", "method": method,
            "sampler": method.split()[0], "swept": swept, "parameters": {}, "seed": 0}
    metrics = {"frames": 100, "keyframes": 50, "candidates": 4, "verified": 3, "false_loops": 0,
               "before": {"ate_translation_m": 2.0}, "after": {"ate_translation_m": ate_after},
               "improvement_pct": {"translation": 100 * (2.0 - ate_after) / 2.0, "rotation": 10.0},
               "pr_auc": 0.9, "f1_max": 0.8, "memory_bytes": {"total": memory}, "peak_rss_bytes": 2**20,
               "time_s": {"backend_total": 1.0}, "fps": 50.0, "backend_fps": 60.0,
               "latency_ms": {"backend": {"p99": 12.0}}}
    (folder / "cell.json").write_text(json.dumps(info))
    (folder / "metrics.json").write_text(json.dumps(metrics))


def test_report_relative_memory_ate_difference_and_sweep_figure(tmp_path):
    _fake_cell(tmp_path, "a", "all", 4000, 0.5, {})
    _fake_cell(tmp_path, "b", "msa lambda_l=0.0", 2000, 0.6, {"lambda_l": 0.0})
    _fake_cell(tmp_path, "c", "msa lambda_l=1.0", 1000, 0.9, {"lambda_l": 1.0})
    (tmp_path / "cells" / ".x.partial-1").mkdir()  # ignored
    result = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert result.exit_code == 0, result.output
    rows = {r["method"]: r for r in make_rows(load_cells(tmp_path))}
    assert rows["msa lambda_l=0.0"]["memory_vs_reference_pct"] == pytest.approx(50.0)
    assert rows["msa lambda_l=1.0"]["memory_vs_reference_pct"] == pytest.approx(25.0)
    for name in ("ate_difference.png", "distance_bounds.png"):
        assert (tmp_path / "figures" / name).is_file()
    assert "| msa lambda_l=1.0 | 50 | 55.0 % |" in (tmp_path / "results.md").read_text()


def test_report_and_experiment_cli_errors(tmp_path):
    with pytest.raises(InputError, match="not an experiment results folder"):
        write_report(tmp_path)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**TINY, "sampler": ["all"]}))
    result = CliRunner().invoke(app, ["experiment", str(bad), "--out", str(tmp_path / "o")])
    assert result.exit_code != 0 and "unknown key 'sampler'" in str(result.exception)
    assert not os.path.exists(tmp_path / "o")
