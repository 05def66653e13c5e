"""KISS-ICP's thread count in the online pipeline: a live source (frames that come once) uses every core and
says the run is not bit-reproducible; recorded data is replayed on one thread; an explicit setting wins. The
count is in metrics.json, report.md and the progress label.

KISS-ICP fixes its thread count once per process, so the multi-threaded run is a separate process here (it
would otherwise change the threads of every later test's odometry)."""

from __future__ import annotations

import json

import yaml
from helpers.cli import run_cli
from helpers.metrics import metrics_json
from test_real_inputs_times import _kitti

from msa_slam.evaluation.metrics import Deskew, RunSetup
from msa_slam.evaluation.metrics_json import from_json
from msa_slam.pipeline import run
from msa_slam.pipeline.config import NOT_REPRODUCIBLE, make_online_config
from msa_slam.pipeline.live import threads_note, with_odometry_threads
from msa_slam.reporting.report import threads_text
from msa_slam.workers import available_cpus

COARSE = "live:figure-eight,stride=4,azimuth_steps=180,realism=clean"


def test_live_source_uses_every_core_and_says_it_is_not_reproducible(tmp_path):
    out = tmp_path / "live"
    done = run_cli(
        "online",
        "-d",
        COARSE,
        "--sampler",
        "all",
        "-p",
        "max_frames=12",
        "--cache-dir",
        str(tmp_path / "cache"),
        "--out",
        str(out),
    )
    assert done.returncode == 0, done.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    cores = available_cpus()
    assert metrics["threads"]["odometry"] == cores
    assert yaml.safe_load((out / "config.yaml").read_text())["odometry_params"]["num_threads"] == cores
    assert f"(odometry: {cores} thread" in done.stderr  # the progress label
    noted = [w for w in metrics["warnings"] if NOT_REPRODUCIBLE in w]
    assert noted == threads_note(cores) and (noted != []) == (cores > 1)
    assert threads_text(from_json(metrics, "metrics.json").setup) in (out / "report.md").read_text()


def test_recorded_source_runs_on_one_thread(tmp_path):
    config = make_online_config(
        dataset=str(_kitti(tmp_path / "seq")), sampler="all", mode="realistic", cache_dir=str(tmp_path / "cache")
    )
    result = run(config)
    assert metrics_json(result)["threads"] == {"odometry": 1, "verification": 1, "blas_backend": 1}
    assert "num_threads" not in result.config.odometry_params  # the default, as before
    assert not [w for w in metrics_json(result)["warnings"] if NOT_REPRODUCIBLE in w]
    assert threads_text(result.metrics.setup) == "Odometry: KISS-ICP on 1 thread (bit-reproducible)."


def test_explicit_thread_count_wins_on_a_live_source():
    config = make_online_config(dataset=COARSE, sampler="all", max_frames=12, odometry_params={"num_threads": 1})
    result = run(config)
    assert metrics_json(result)["threads"]["odometry"] == 1 and result.config.odometry_params["num_threads"] == 1
    assert not [w for w in metrics_json(result)["warnings"] if NOT_REPRODUCIBLE in w]


def test_thread_default_leaves_other_odometries_and_given_counts_alone():
    given = make_online_config(dataset=COARSE, odometry_params={"num_threads": 0})
    assert with_odometry_threads(given, 2) is given
    noisy = make_online_config(dataset=COARSE, odometry="gt-noise")
    assert with_odometry_threads(noisy, 2) is noisy
    assert with_odometry_threads(make_online_config(dataset=COARSE), 2).odometry_params == {"num_threads": 2}
    assert threads_note(1) == [] and threads_note(None) == []
    no_kiss = Deskew(None, "not KISS-ICP")
    assert threads_text(RunSetup(no_kiss, {"odometry": None})) == "" and threads_text(RunSetup(no_kiss, {})) == ""
