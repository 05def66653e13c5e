"""benchmarks/bench_peer.py: how it tells that the peer (KISS-SLAM) is missing and how to install it, and its
table with the peer's rows n/a (the runs themselves are the simulator's, the pipeline's and the peer's)."""

from __future__ import annotations

import importlib.util
import sys

import pytest
from helpers.benchmarks import loaded_benchmark


@pytest.fixture(scope="module")
def bench():
    yield from loaded_benchmark("bench_peer")


def test_a_python_without_the_peer_is_named_with_the_import_error(bench):
    if importlib.util.find_spec("kiss_slam") is not None:
        pytest.skip("kiss-slam is installed in this Python")
    why = bench.peer_missing(sys.executable)
    assert why is not None and "kiss_slam" in why
    message = bench.INSTALL.format(python=sys.executable, error=why)
    assert "pip install 'kiss-slam>=0.0.2'" in message and "--peer-python" in message and why in message


def test_a_missing_interpreter_is_reported_not_raised(bench, tmp_path):
    assert "No such file" in bench.peer_missing(str(tmp_path / "no-python"))


def test_table_prints_missing_values_as_na(bench):
    rows = [
        {"estimator": "KISS-SLAM", "ape": None, "rot": None, "loops": None, "time": None, "note": "peer not installed"},
        {
            "estimator": "msa-slam msa",
            "ape": 1.23456,
            "rot": 0.5,
            "loops": "3 of 9 cand.",
            "time": 61.04,
            "note": "40 keyframes",
        },
    ]
    text = bench.table(rows, {"sequence": "simulated KITTI-07", "seed": 0, "frames": 1101, "compare_wall_s": None})
    lines = text.splitlines()
    assert lines[0] == "### simulated KITTI-07, world seed 0, 1101 frames"
    assert "| KISS-SLAM | n/a | n/a |  | n/a | peer not installed |" in lines
    assert "| msa-slam msa | 1.235 | 0.500 | 3 of 9 cand. | 61.0 | 40 keyframes |" in lines


def test_the_peer_is_scored_against_the_truth_at_sweep_end(bench):
    # mid-sweep truth accelerating on a weaving path (x = 2 t^2, y = sin t), frames 0.1 s apart: the sweep-end truth is the pose
    # 0.05 s later (interpolated linearly between frames: within 6 mm), the last frame's extrapolated
    import numpy as np

    stamps = np.arange(50) * 0.1

    def path(t):
        poses = np.tile(np.eye(4), (len(t), 1, 1))
        poses[:, 0, 3], poses[:, 1, 3] = 2.0 * t**2, np.sin(t)
        return poses

    end = bench.sweep_end_truth(path(stamps), stamps)
    assert np.linalg.norm(end[:-1, :3, 3] - path(stamps + 0.05)[:-1, :3, 3], axis=1).max() < 0.006
    assert end[-1, 0, 3] > path(stamps)[-1, 0, 3] + 0.45  # extrapolated half a frame at the last speed
    peer = path(stamps + 0.05)  # a peer that deskews to the sweep's end and has no drift
    assert bench.ape(peer, end)[0] < 0.006 < bench.ape(peer, path(stamps))[0]


def test_speed_jobs_are_the_chosen_ones_in_a_fixed_order(bench, tmp_path):
    import peer_timing

    chosen = peer_timing.jobs(tmp_path, tmp_path, "", "/peer/python", tmp_path / "driver.py", 1, ("run", "peer"))
    assert list(chosen) == ["KISS-SLAM", "msa-slam run --sampler msa"]
    assert chosen["KISS-SLAM"][0] == "/peer/python" and "--threads" in chosen["KISS-SLAM"]
    without_peer = peer_timing.jobs(tmp_path, tmp_path, "", None, tmp_path / "driver.py", 1, ("peer", "compare"))
    assert list(without_peer) == ["msa-slam compare (7 methods)"]
