"""Same input, same answer: two cold runs give bitwise-identical results, and KISS-ICP's
settings come from msa-slam's configuration only, never from kiss_icp_* environment variables."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from kiss_icp.config.parser import KISSConfig

from msa_slam.datasets import open_dataset
from msa_slam.errors import InputError
from msa_slam.odometry import KissOdometry
from msa_slam.odometry.kiss import PARAMETERS

# sim:test with coarser KISS-ICP voxels: ~4x faster odometry, same keyframes-and-loops pipeline.
RUN = ["run", "--dataset", "sim:test", "-p", "odometry.voxel_size=1.5", "--quiet"]
WALL_CLOCK_KEYS = {"time_s", "frontend_time_s", "peak_rss_bytes", "frontend_cached"}


def _wall_clock(key: str) -> bool:
    """Metrics that measure the machine or the cache rather than the result (times, RSS, cache hits)."""
    return (
        key in WALL_CLOCK_KEYS
        or "_ms" in key
        or "rss" in key
        or "cached" in key
        or "realtime" in key
        or key.endswith("_s")
    )


def _result_metrics(value):
    if isinstance(value, dict):
        return {k: _result_metrics(v) for k, v in value.items() if not _wall_clock(k)}
    return value


def _cold_run(root: Path, name: str, options: list[str]) -> tuple[Path, Path]:
    """`msa-slam run` with `options` in a fresh process with its own empty cache (simulation, odometry,
    descriptors)."""
    cache, out = root / f"cache-{name}", root / f"out-{name}"
    code = "import sys; from msa_slam.cli import main; sys.argv = ['msa-slam', *sys.argv[1:]]; main()"
    # The cache root comes from the environment: --cache-dir would be recorded in config.yaml.
    env = {**os.environ, "MSA_SLAM_CACHE": str(cache)}
    done = subprocess.run(
        [sys.executable, "-c", code, *RUN, *options, "--out", str(out)],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    return out, cache


def _cached(cache: Path, kind: str) -> np.ndarray:
    files = sorted(cache.rglob(f"{kind}-*.npy"))
    assert len(files) == 1, files
    return np.load(files[0])


# Slow (two cold `run`s of sim:test in fresh processes, about 50 s of CPU, in each mode: oracle, the default, and
# realistic, whose loops the verified protocol accepts by registration; `make test-slow`; CI runs it): the default
# suite compares the bytes of a serial and a two-worker comparison (test_compare_workers.py) and of simulations
# written by one process and by a pool (test_sim.py), and pins run's results (test_golden_outputs.py).
@pytest.mark.slow
@pytest.mark.parametrize("options", [[], ["--mode", "realistic"]], ids=["oracle", "realistic"])
def test_two_cold_runs_are_bitwise_identical(tmp_path, options):
    (a, cache_a), (b, cache_b) = _cold_run(tmp_path, "a", options), _cold_run(tmp_path, "b", options)
    files = [
        "config.yaml",
        "frames.csv",
        "loops.csv",
        *sorted(str(p.relative_to(a)) for p in (a / "trajectories").iterdir()),
    ]
    assert len(files) > 3
    for name in files:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    metrics_a, metrics_b = (json.loads((d / "metrics.json").read_text()) for d in (a, b))
    assert metrics_a["keyframes"] > 3 and metrics_a["verified"] > 0  # a run with keyframes and loops
    assert _result_metrics(metrics_a) == _result_metrics(metrics_b)
    # The written files round poses; the cached front end holds them at full precision (issue: 6e-14 m).
    for kind in ("odometry", "descriptors"):
        np.testing.assert_array_equal(_cached(cache_a, kind), _cached(cache_b, kind), err_msg=kind)


def test_kiss_icp_environment_variables_change_nothing(sequence, monkeypatch):
    scans = [open_dataset(sequence)[i].points for i in range(6)]
    clean = KissOdometry()
    expected = np.stack([clean.register(points) for points in scans])
    monkeypatch.setenv("kiss_icp_registration", '{"max_num_iterations": 1}')
    monkeypatch.setenv("kiss_icp_data", '{"max_range": 5.0, "deskew": true}')
    monkeypatch.setenv("kiss_icp_mapping", '{"max_points_per_voxel": 1}')
    assert KISSConfig().registration.max_num_iterations == 1  # the variables do reach KISS-ICP's own loader
    influenced = KissOdometry()
    assert influenced.config == clean.config
    np.testing.assert_array_equal(np.stack([influenced.register(points) for points in scans]), expected)


def test_config_is_the_full_effective_kiss_icp_config():
    config = KissOdometry(max_range=80.0, num_threads=1).config
    sections = {name for name in KISSConfig.model_fields if name != "out_dir"}
    assert sections <= set(config)
    for name in sections:
        assert set(config[name]) == set(KISSConfig.model_fields[name].annotation.model_fields), name
    assert config["registration"]["max_num_threads"] == 1  # threads change results: part of the cache key
    assert config["mapping"]["voxel_size"] == 0.8 and config["registration"]["max_num_iterations"] == 500
    assert config["kiss_icp_version"]


@pytest.mark.parametrize(
    ("params", "problem"),
    [
        ({"num_threads": -1}, "num_threads=-1: must be an integer >= 0"),
        ({"num_threads": "abc"}, "num_threads='abc'"),
        ({"max_range": float("nan")}, "max_range=nan: must be a finite number > 0"),
        ({"voxel_size": 0}, "voxel_size=0"),
        ({"max_num_iterations": 0}, "max_num_iterations=0"),
        ({"deskew": "yes"}, "deskew='yes': must be true or false"),
    ],
)
def test_bad_kiss_parameters_name_the_key(params, problem):
    with pytest.raises(InputError, match=problem.replace("(", r"\(")):
        KissOdometry(**params)


def test_thread_count_cannot_change_within_a_process():
    KissOdometry(num_threads=1)  # msa-slam's default: this process runs KISS-ICP single-threaded
    with pytest.raises(InputError, match="num_threads=0: KISS-ICP already runs with num_threads=1"):
        KissOdometry(num_threads=0)


def test_params_rebuild_the_same_odometry():
    odometry = KissOdometry(max_range=80.0, max_num_iterations=100)
    assert set(odometry.params) == set(PARAMETERS)
    assert odometry.params["voxel_size"] == 0.8 and odometry.params["num_threads"] == 1
    assert KissOdometry(**odometry.params).config == odometry.config
