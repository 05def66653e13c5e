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
    rows = [{"estimator": "KISS-SLAM", "ape": None, "rot": None, "loops": None, "time": None,
             "note": "peer not installed"},
            {"estimator": "msa-slam msa", "ape": 1.23456, "rot": 0.5, "loops": "3 of 9 cand.", "time": 61.04,
             "note": "40 keyframes"}]
    text = bench.table(rows, {"sequence": "simulated KITTI-07", "seed": 0, "frames": 1101, "compare_wall_s": None})
    lines = text.splitlines()
    assert lines[0] == "### simulated KITTI-07, world seed 0, 1101 frames"
    assert "| KISS-SLAM | n/a | n/a |  | n/a | peer not installed |" in lines
    assert "| msa-slam msa | 1.235 | 0.500 | 3 of 9 cand. | 61.0 | 40 keyframes |" in lines
