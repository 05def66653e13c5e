"""Fault injection: each command killed (SIGKILL) at a cache write, in the middle of building its result
folder and just before that folder moves into place; a rerun must give the uninterrupted result with no
leftovers (no partial folders, temporary files or lock files beside --out or in the cache)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.cli import main_in_process
from helpers.results import differences, stable_content
from helpers.signals import terminal_signals

DRIVER = Path(__file__).parent / "helpers" / "fault_driver.py"
DATASET = "sim:test,end=80"  # 40 frames of the figure-eight: seconds per run


def cli(
    tmp: Path, where: str, args: list[str], cache: Path, out: Path, occurrence: int = 1
) -> subprocess.CompletedProcess:
    env = {**os.environ, "MSA_FAULT_CACHE": str(cache), "MSA_FAULT_OUT": str(out)}
    return subprocess.run(
        [sys.executable, str(DRIVER), where, str(occurrence), "--", *args],
        cwd=tmp,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        preexec_fn=terminal_signals,
    )


def leftovers(*folders: Path) -> list[str]:
    """Names that only a killed writer leaves behind."""
    found = []
    for folder in folders:
        if folder.is_dir():
            found += [
                str(p)
                for p in folder.rglob("*")
                if p.name.endswith((".tmp", ".lock")) or ".partial-" in p.name or ".old-" in p.name
            ]
    return found


def command(name: str, tmp: Path, out: Path, cache: Path) -> list[str]:
    if name == "sample":
        return [
            "sample",
            "--poses",
            str(tmp / "poses.txt"),
            "--descriptors",
            str(tmp / "desc.npy"),
            "-p",
            "window=6",
            "--out",
            str(out),
            "--quiet",
        ]
    extra = ["--sampler", "msa"] if name in ("run", "online") else []
    return [name, "--dataset", DATASET, *extra, "--out", str(out), "--cache-dir", str(cache), "--quiet"]


@pytest.fixture
def stream_files(tmp_path: Path) -> Path:
    import numpy as np

    from msa_slam.io.poses import write_poses

    poses = np.tile(np.eye(4), (40, 1, 1))
    poses[:, 0, 3] = np.arange(40) * 1.2
    write_poses(tmp_path / "poses.txt", poses)
    np.save(tmp_path / "desc.npy", np.random.default_rng(1).random((40, 16)))
    return tmp_path


def kills_then_rerun(name: str, tmp: Path, kill_points: list[str]) -> None:
    out, cache = tmp / "results" / "out", tmp / "cache"
    (tmp / "results").mkdir()
    done = cli(tmp, "none", command(name, tmp, out, cache), cache, out)
    assert done.returncode == 0, done.stderr
    expected = stable_content(out)
    shutil.rmtree(out)
    if cache.exists():
        cache.rename(tmp / "warm-cache")  # the killed runs start cold, with the same paths (config.yaml names them)
    for where in kill_points:
        killed = cli(tmp, where, command(name, tmp, out, cache), cache, out)
        assert killed.returncode == -signal.SIGKILL, f"{name} not killed at {where}: {killed.stderr}"
        assert not out.exists(), f"{name} killed at {where} left a result folder that looks complete"
    rerun = cli(tmp, "none", command(name, tmp, out, cache), cache, out)
    assert rerun.returncode == 0, rerun.stderr
    assert differences(stable_content(out), expected) == []
    assert leftovers(tmp / "results", cache) == []
    assert sorted(p.name for p in (tmp / "results").iterdir()) == ["out"]


# Slow (five `run` processes, about a minute of CPU; `make test-slow`; CI runs it): the default suite kills
# `sample` at the same staging and final renames below, and test_trust_writers.py repairs a damaged simulation in the cache.
@pytest.mark.slow
def test_run_killed_at_cache_staging_and_final_rename(tmp_path):
    kills_then_rerun("run", tmp_path, ["cache", "staging", "final"])


@pytest.mark.slow
@pytest.mark.parametrize("name", ["online", "compare"])
def test_online_and_compare_killed_at_cache_staging_and_final_rename(name, tmp_path):
    kills_then_rerun(name, tmp_path, ["cache", "staging", "final"])


def test_sample_killed_while_staging_and_before_final_rename(stream_files):
    kills_then_rerun("sample", stream_files, ["staging", "final"])


# Slow (four `experiment` processes; `make test-slow`; CI runs it): test_experiments.py resumes a grid past a
# killed cell's partial folder in the default suite.
@pytest.mark.slow
def test_experiment_killed_while_writing_cells_resumes_to_the_same_result(tmp_path):
    """The grid folder grows in place: killed while a cell is staged and again as the second cell moves in,
    a resumed run finishes the grid exactly as an uninterrupted one."""
    out, cache = tmp_path / "results" / "grid", tmp_path / "cache"
    (tmp_path / "results").mkdir()
    args = ["experiment", "tiny", "--out", str(out), "--quiet"]
    assert cli(tmp_path, "none", args, cache, out).returncode == 0
    expected = stable_content(out)
    shutil.rmtree(out)
    for where, occurrence in (("staging", 1), ("inside", 2)):
        killed = cli(tmp_path, where, args, cache, out, occurrence)
        assert killed.returncode == -signal.SIGKILL, killed.stderr
    rerun = cli(tmp_path, "none", args, cache, out)
    assert rerun.returncode == 0, rerun.stderr
    assert differences(stable_content(out), expected) == []
    assert leftovers(tmp_path / "results") == []


def test_kill_after_the_final_rename_keeps_the_new_result(stream_files, monkeypatch, capsys):
    """Killed after the result moved into place but before its lock was released: the result stands and a
    rerun with --overwrite replaces it cleanly. (No process is killed here: both runs run in the test's.)"""
    tmp = stream_files
    out = tmp / "out"
    args = command("sample", tmp, out, tmp / "cache")
    assert main_in_process(monkeypatch, capsys, *args).returncode == 0
    lock = tmp / ".out.lock"
    lock.write_text("")  # what a kill after the rename leaves: the lock file (its flock died with the process)
    first = stable_content(out)
    rerun = main_in_process(monkeypatch, capsys, *args, "--overwrite")
    assert rerun.returncode == 0, rerun.stderr
    assert differences(stable_content(out), first) == [] and not lock.exists()
    shutil.rmtree(out)
