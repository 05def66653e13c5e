"""Inputs a user must be able to trust: a bad calib.txt, too few points to register, a grid's cost
stated before it starts, and no compile process left running after its demo is killed."""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.cli import main_in_process
from helpers.orphans import poll, proc_stat
from scipy.spatial.transform import Rotation
from test_experiments import TINY

from msa_slam.datasets import open_dataset
from msa_slam.errors import InputError
from msa_slam.experiments import expand, parse_grid
from msa_slam.io.poses import format_kitti
from msa_slam.odometry import KissOdometry


def _kitti_with_tr(root: Path, tr_line: str) -> Path:
    """A 3-scan KITTI-layout sequence whose (rotating) poses are converted by the given calib.txt Tr line."""
    seq = root / "07"
    (seq / "velodyne").mkdir(parents=True)
    for k in range(3):
        np.random.default_rng(k).normal(size=(50, 4)).astype(np.float32).tofile(seq / "velodyne" / f"{k:06d}.bin")
    (seq / "calib.txt").write_text("P0: " + " ".join(["0"] * 12) + "\n" + tr_line + "\n")
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("z", np.arange(3)[:, None] * 0.3).as_matrix()
    poses[:, 0, 3] = np.arange(3)
    (seq / "poses.txt").write_text(format_kitti(poses))
    return seq


def test_a_non_rigid_tr_is_named_in_calib_txt_not_as_a_pose(tmp_path):
    """A scaled Tr was reported as "poses: frame 1 is not a rigid transform", naming neither calib.txt nor Tr."""
    seq = _kitti_with_tr(tmp_path, "Tr: 1.1 0 0 0 0 1 0 0 0 0 1 0")
    calib = seq / "calib.txt"
    with pytest.raises(InputError) as err:
        open_dataset(seq)
    assert str(err.value) == (
        f"{calib}:2: Tr (the Velodyne->camera extrinsic) is not a rigid transform "
        "(|R R^T - I| = 2.10e-01, det R = 1.100000); it must be a rotation and a translation"
    )


def test_a_scan_too_sparse_to_register_is_extrapolated_and_named(caplog):
    """A 1-point scan was registered (one point cannot fix a pose) with no word; now it is not registered, its
    pose is KISS-ICP's constant-velocity prediction, and the frame is named in the log and the run's notes."""
    scene = np.random.default_rng(1).normal(size=(2000, 3)) * 10.0
    odometry = KissOdometry(max_range=50.0)
    with caplog.at_level(logging.WARNING, logger="msa_slam.odometry.kiss"):
        poses = [odometry.register(scene - [0.5 * k, 0.0, 0.0]) for k in range(3)]
        poses.append(odometry.register(np.array([[5.0, 1.0, 0.0]])))
        poses.append(odometry.register(np.array([[5.0, 1.0, 0.0], [60.0, 0.0, 0.0], [0.0, 7.0, 1.0]])))
    assert odometry.unregistered_frames == [3, 4]
    assert [r.getMessage() for r in caplog.records] == [
        "KISS-ICP frame 3: it has only 1 point (registration needs 3), so it was not registered (pose extrapolated "
        "at constant velocity)",
        "KISS-ICP frame 4: only 2 of its 3 points lie within 0-50 m (registration needs 3), so it was not "
        "registered (pose extrapolated at constant velocity)",
    ]
    np.testing.assert_allclose(poses[3], poses[2] @ np.linalg.inv(poses[1]) @ poses[2], atol=1e-9)
    assert odometry.unregistered_warning(5) == [
        "odometry: KISS-ICP could not register 2 of 5 frames (frames 3, 4): fewer than 3 of their points lie within "
        "0-50 m, so their poses were extrapolated at constant velocity"
    ]


def test_a_grid_states_its_cells_and_time_before_it_starts_and_the_time_left_as_it_runs(tmp_path, monkeypatch, capsys):
    """A grid started with no word on its cost. Off a terminal (as here) too: first a line with the cell counts
    and an estimated time with its basis (a first run: assumed stage costs; a resume: what the finished cells
    recorded), then the progress with the time left."""
    grid_file, out = tmp_path / "g.yaml", tmp_path / "o"
    grid_file.write_text(yaml.safe_dump(TINY))
    first = main_in_process(monkeypatch, capsys, "experiment", str(grid_file), "--out", str(out))
    assert first.returncode == 0, first.stderr
    lines = first.stderr.splitlines()
    assert re.fullmatch(
        r"grid t: 2 cells, 0 finished earlier, 2 to run; estimated time \d+ s \(rough: each cell's "
        r"frames times an assumed cost a frame of its stages on a 2-core machine like this project's: "
        r"simulation 27 ms, kiss-icp 126 ms for 46080 points a scan \(scaled by a scan's points\), "
        r"descriptor 7 ms, back end 17 ms; on 1 worker; start-up and writing results not included\)",
        lines[0],
    ), lines[0]
    assert lines[1] == "grid t (0 done before): start (2)"
    assert re.fullmatch(r".*: 1/2 \(50 %\), [\d.]+ s, ~\d+ s left", lines[2]), lines[2]

    kept, rerun = expand(parse_grid(TINY))
    shutil.rmtree(out / "cells" / rerun.id)
    metrics = json.loads((out / "cells" / kept.id / "metrics.json").read_text())
    recorded = sum(v for k, v in metrics["time_s"].items() if k != "backend_total")
    per_frame = recorded / metrics["frames"]
    second = main_in_process(monkeypatch, capsys, "experiment", str(grid_file), "--out", str(out))
    assert second.returncode == 0, second.stderr
    assert second.stderr.splitlines()[0] == (
        f"grid t: 2 cells, 1 finished earlier, 1 to run; estimated time {per_frame * metrics['frames']:.0f} s "
        f"(the stage times 1 finished cell(s) of this grid recorded (metrics.json time_s), {1e3 * per_frame:.3g} ms "
        "a frame, times each cell's frames; on 1 worker; start-up and writing results not included)"
    )


# The demo's role: start the background compile, then work until killed (stdin stays open until then).
_COMPILING_PARENT = """
import sys
from msa_slam.sampling.msa.warm import compile_in_background
print(compile_in_background({}, (20, 60)).pid, flush=True)
sys.stdin.read()
"""
# The same with a child that has only the fallback (a thread watching its parent) and creates READY once set up.
_WATCHED_PARENT = f"""
import multiprocessing, os, sys
sys.path.insert(0, {str(Path(__file__).parent)!r})
from helpers.orphans import fallback_child
child = multiprocessing.get_context("spawn").Process(target=fallback_child, args=(os.getpid(), sys.argv[1]),
                                                     daemon=True)
child.start()
print(child.pid, flush=True)
sys.stdin.read()
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc")
@pytest.mark.parametrize("when", ["compiling", "starting", "fallback"])
def test_a_killed_parent_takes_its_compile_child_with_it(tmp_path, when):
    """kill -9 of the demo left its compile process running on for minutes. `compiling`: killed once the child
    lowered its priority (it is past its start-up); `starting`: killed at once, maybe before the child set up
    anything; `fallback`: a child with only the thread watching its parent (no prctl), killed once that runs.
    An empty numba cache makes the compile child compile (about a minute of CPU) rather than load."""
    script, ready = (_WATCHED_PARENT if when == "fallback" else _COMPILING_PARENT), tmp_path / "ready"
    parent = subprocess.Popen(
        [sys.executable, "-c", script, str(ready)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)},
    )
    child = int(parent.stdout.readline())
    try:
        if when == "compiling":
            assert poll(lambda: (proc_stat(child) or [""] * 17)[16] == "19", timeout=60)
        elif when == "fallback":
            assert poll(ready.exists, timeout=60), "the child did not set up its end with the parent"
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        assert poll(lambda: proc_stat(child) is None, timeout=30), "the compile child outlived its killed parent"
    finally:
        parent.kill()
        parent.wait()
        parent.stdout.close()
        parent.stdin.close()
        if proc_stat(child) is not None:
            os.kill(child, signal.SIGKILL)
