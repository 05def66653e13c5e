"""`msa-slam run` end to end on the small simulated sequence: every output of a result folder."""

from __future__ import annotations

import csv
import inspect
import json

import numpy as np
import pytest
from helpers.methods import before_method, degenerate
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import sampler_realtime_fraction
from msa_slam.io.poses import read_poses
from msa_slam.pipeline import load_config
from msa_slam.pipeline.driver import RUN_SWEEP_NOT_RUN

runner = CliRunner()


@pytest.fixture(scope="module")
def run_folder(sequence, odometry_file, cache_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "run"
    result = runner.invoke(
        app,
        [
            "run",
            "--dataset",
            str(sequence),
            "--odometry",
            str(odometry_file),
            "--sampler",
            "constant",
            "--param",
            "distance=3",
            "--param",
            "graph.robust=huber",
            "--descriptor",
            "sc",
            "--mode",
            "oracle",
            "--cache-dir",
            str(cache_dir),
            "--out",
            str(out),
            "--quiet",
        ],
    )
    assert result.exit_code == 0, result.output
    assert result.output.strip() == str(out / "report.md")
    return out


def test_run_writes_config_and_metrics(run_folder, sequence):
    cfg = load_config(run_folder / "config.yaml")
    assert cfg.sampler == "constant" and cfg.sampler_params == {"distance": 3}
    assert cfg.graph.robust == "huber" and cfg.dataset == str(sequence)
    metrics = json.loads((run_folder / "metrics.json").read_text())
    for key in (
        "keyframes",
        "candidates",
        "verified",
        "false_loops",
        "before",
        "after",
        "improvement_pct",
        "pr_auc",
        "f1_max",
        "memory_bytes",
        "peak_rss_bytes",
        "time_s",
    ):
        assert key in metrics
    assert metrics["after"]["ate_translation_m"] < metrics["before"]["ate_translation_m"]
    assert len(metrics["keyframe_frames"]) == metrics["keyframes"]


def test_run_writes_frames_and_trajectories(run_folder):
    metrics = json.loads((run_folder / "metrics.json").read_text())
    rows = list(csv.DictReader((run_folder / "frames.csv").open()))
    assert len(rows) == metrics["frames"]
    keyframes = [r for r in rows if r["is_keyframe"] == "1"]
    assert [int(r["frame"]) for r in keyframes] == metrics["keyframe_frames"]
    assert all(r["opt_x"] and r["ate_opt_m"] for r in keyframes)
    assert not any(r["opt_x"] for r in rows if r["is_keyframe"] == "0")
    for name, length in (
        ("optimised_keyframes", metrics["keyframes"]),
        ("gt_keyframes", metrics["keyframes"]),
        ("odometry", metrics["frames"]),
    ):
        kitti, _ = read_poses(run_folder / "trajectories" / f"{name}.kitti", "kitti")
        tum, times = read_poses(run_folder / "trajectories" / f"{name}.tum", "tum")
        assert len(kitti) == len(tum) == length
        assert abs(kitti[:, :3, 3] - tum[:, :3, 3]).max() < 1e-6
    loops = list(csv.DictReader((run_folder / "loops.csv").open()))
    assert len(loops) == metrics["candidates"]
    assert sum(int(r["accepted"]) for r in loops) == metrics["verified"]


def test_run_writes_figures_and_report(run_folder):
    for name in ("trajectories.png", "pr_curve.png"):
        assert (run_folder / "figures" / name).read_bytes()[:4] == b"\x89PNG"
    report = (run_folder / "report.md").read_text()
    assert "| ATE translation [m], full rate |" in report and "figures/trajectories.png" in report
    assert not [p for p in run_folder.parent.iterdir() if p.name.startswith(".")]  # no partial folders left


def test_run_leaves_out_the_sweep_by_default(run_folder):
    """The threshold sweep is an analysis, not part of a SLAM run: `run` without --sweep skips it and says how
    to add it."""
    metrics = json.loads((run_folder / "metrics.json").read_text())
    assert metrics["threshold_sweep"] is None and metrics["time_s"]["threshold_sweep"] is None
    assert metrics["unavailable"]["threshold_sweep"] == RUN_SWEEP_NOT_RUN
    report = (run_folder / "report.md").read_text()
    assert f"threshold sensitivity n/a: {RUN_SWEEP_NOT_RUN}" in report and "--sweep" in RUN_SWEEP_NOT_RUN
    assert "Threshold sensitivity (only loop closing" not in report


@pytest.fixture(scope="module")
def swept_folder(sequence, odometry_file, cache_dir, tmp_path_factory):
    """MSA (the default sampler: window optimisations to time) with --sweep."""
    out = tmp_path_factory.mktemp("cli") / "swept"
    result = runner.invoke(
        app,
        [
            "run",
            "--dataset",
            str(sequence),
            "--odometry",
            str(odometry_file),
            "--sweep",
            "--cache-dir",
            str(cache_dir),
            "--out",
            str(out),
            "--quiet",
        ],
    )
    assert result.exit_code == 0, result.output
    return out


def test_run_with_sweep_writes_it(swept_folder):
    metrics = json.loads((swept_folder / "metrics.json").read_text())
    assert [row["threshold"] for row in metrics["threshold_sweep"]][0] == pytest.approx(0.70)
    assert "threshold_sweep" not in metrics["unavailable"] and metrics["time_s"]["threshold_sweep"] > 0
    report = (swept_folder / "report.md").read_text()
    assert "Threshold sensitivity (only loop closing" in report and RUN_SWEEP_NOT_RUN not in report


def test_run_reports_the_samplers_time_over_the_datas_duration(swept_folder, sequence):
    metrics = json.loads((swept_folder / "metrics.json").read_text())
    times = np.loadtxt(sequence / "times.txt")
    sampling_s = metrics["sampler_stats"]["optimisation_ms_total"] / 1e3
    assert metrics["sampler_stats"]["window_optimisations"] > 0 and sampling_s > 0
    assert metrics["sampler_realtime_fraction"] == pytest.approx(sampling_s / (times[-1] - times[0]))
    assert "sampler_realtime_fraction" not in metrics["unavailable"]
    report = (swept_folder / "report.md").read_text()
    assert f"Sampler time over the data's duration: {metrics['sampler_realtime_fraction']:.4f}" in report


def test_sampler_realtime_fraction_of_known_and_unknown_times():
    """0.5 s of window optimisation over 10 s of data is 5 % of real time; frame numbers give no duration."""
    stats = {"optimisation_ms_total": 500.0}
    times = np.linspace(0.0, 10.0, 101)
    assert sampler_realtime_fraction(stats, times, times_known=True) == 0.05
    assert "no timestamps" in sampler_realtime_fraction(stats, np.arange(101.0), times_known=False).reason
    assert "span no time" in sampler_realtime_fraction(stats, np.zeros(5), times_known=True).reason


def test_run_reports_bad_input(tmp_path, cache_dir):
    result = runner.invoke(
        app,
        [
            "run",
            "--dataset",
            str(tmp_path / "missing"),
            "--cache-dir",
            str(cache_dir),
            "--out",
            str(tmp_path / "out"),
            "--quiet",
        ],
    )
    assert isinstance(result.exception, InputError) and "missing" in str(result.exception)
    result = runner.invoke(app, ["run", "--dataset", "sim:test", "--param", "thresold=0.5", "--quiet"])
    assert isinstance(result.exception, InputError) and "thresold" in str(result.exception)
    assert not (tmp_path / "out").exists()


def test_compare_keeps_finished_methods_when_one_fails(sequence, odometry_file, cache_dir, tmp_path, monkeypatch):
    """One method failing at run time (here: made to fail) leaves the others' results, the failure marked in
    report.md with its traceback, and exit code 1 with one line naming the method."""
    import msa_slam.experiments.compare as compare

    methods = (("constant-3m", "constant", {"distance": 3.0}), ("entropy", "entropy", {}))
    monkeypatch.setattr(compare, "PAPER_METHODS", methods)
    with_defaults = [
        name
        for name, p in inspect.signature(compare.run_compare).parameters.items()
        if p.default is not inspect.Parameter.empty
    ]
    defaults = list(compare.run_compare.__defaults__)
    defaults[with_defaults.index("methods")] = methods
    monkeypatch.setattr(compare.run_compare, "__defaults__", tuple(defaults))
    before_method(monkeypatch, "entropy", degenerate)
    out = tmp_path / "cmp"
    result = runner.invoke(
        app,
        [
            "compare",
            "--dataset",
            str(sequence),
            "--odometry",
            str(odometry_file),
            "--cache-dir",
            str(cache_dir),
            "--out",
            str(out),
            "--quiet",
        ],
    )
    assert result.exit_code == 1
    assert "failed: entropy: RuntimeError: degenerate scan statistics" in result.output
    report = (out / "report.md").read_text()
    assert "| constant-3m |" in report and "- entropy: RuntimeError: degenerate scan statistics" in report
    assert (out / "runs" / "constant-3m" / "metrics.json").is_file()
    assert "degenerate scan statistics" in (out / "runs" / "entropy" / "error.txt").read_text()


def test_run_records_effective_odometry_config_threads_and_degenerate_odometry(sequence, cache_dir, tmp_path):
    """A stalled KISS-ICP (coarse azimuth: too few points) is named in metrics and report.md, and the full
    effective odometry configuration with its thread counts is recorded."""
    out = tmp_path / "stalled"
    result = runner.invoke(
        app,
        [
            "run",
            "--dataset",
            "sim:test,azimuth_steps=180",
            "--sampler",
            "all",
            "--cache-dir",
            str(cache_dir),
            "--out",
            str(out),
            "--quiet",
        ],
    )
    assert result.exit_code == 0, result.output
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["threads"] == {"odometry": 1, "verification": 1, "blas_backend": 1}
    assert metrics["odometry_config"]["method"] == "kiss_icp"
    assert metrics["odometry_config"]["registration"]["max_num_threads"] == 1
    stalled = [w for w in metrics["warnings"] if "odometry" in w]
    assert stalled, metrics["warnings"]
    assert stalled[0] in (out / "report.md").read_text()
