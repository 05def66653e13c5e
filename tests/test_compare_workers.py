"""`compare --workers N`: the methods (of each seed) run in N processes forked after the shared front end
(msa_slam.workers), and write the same files as one after another in one process, but for the measured times and
memory; a method failing in a worker is reported as in a serial run; the workers run single-threaded and end with
their parent.

Three methods on the simulated test sequence with drifted odometry from a pose file and loose loop gates (as
test_pipeline, but a similarity threshold of 0.6 instead of 0.4: at 0.4 the threshold sweep's replays at 0.3 and
0.35 verify six times as many loop candidates, and each comparison costs four times as much, for nothing this file
checks) in realistic mode with the paper's loop protocol, so that loops are verified with small_gicp: with two
workers one of them runs two methods, so a worker's first and a later method are both compared.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.methods import before_method, degenerate
from helpers.orphans import poll, proc_stat
from helpers.results import differences, stable_content
from helpers.signals import terminal_signals
from test_compare_resume import _no_rss_growth
from test_pipeline import PERMISSIVE
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.errors import InputError
from msa_slam.experiments.compare import MethodsFailed, run_compare
from msa_slam.pipeline import make_config
from msa_slam.workers import forked_workers

METHODS = (("all", "all", {}), ("constant-2m", "constant", {"distance": 2.0}), ("msa", "msa", {}))
SIMILARITY = 0.6  # every method still verifies loops (22, 22 and 8 of them)


@pytest.fixture(scope="module")
def base(sequence, odometry_file, cache_dir):
    return make_config(
        dataset=str(sequence),
        odometry=str(odometry_file),
        cache_dir=str(cache_dir),
        mode="realistic",
        loop_protocol="paper",  # the threshold's protocol, whose sweep the msa run writes
        **{**PERMISSIVE, "similarity_threshold": SIMILARITY},
    )


@pytest.fixture(scope="module")
def short(base):
    """`base` on the sequence's first 40 scans, for the tests of how a method fails: which method fails and what is
    written do not depend on the sequence's length."""
    return make_config({**base.dump(), "source": {"frames": 40}})


def _same_files(serial: Path, parallel: Path) -> None:
    assert differences(stable_content(serial), stable_content(parallel)) == []


def test_two_workers_write_the_files_of_a_serial_run(base, tmp_path):
    serial = run_compare(base, tmp_path / "serial", methods=METHODS, workers=1, figures=False).parent
    parallel = run_compare(base, tmp_path / "parallel", methods=METHODS, workers=2, figures=False).parent
    _same_files(serial, parallel)
    content = stable_content(parallel)
    assert {f"runs/{name}/metrics.json" for name, _, _ in METHODS} <= set(content)
    assert [m["method"] for m in content["comparison.json"]] == [name for name, _, _ in METHODS]  # method order
    verified = {m["method"]: m["verified"] for m in content["comparison.json"]}
    assert sum(verified.values()) > 0 and content["runs/msa/metrics.json"]["threshold_sweep"], verified
    assert "in each of 2 worker processes" in (parallel / "report.md").read_text()


def test_seeds_with_two_workers_write_the_files_of_a_serial_run(tmp_path, cache_dir, monkeypatch):
    """Each seed's methods in the workers (two methods on a 60-scan prefix of two worlds, as test_compare_resume);
    the RSS growth, which seeds.csv holds as rows, pinned as there."""
    _no_rss_growth(monkeypatch)  # the workers inherit the patch by fork
    base = make_config(dataset="sim:test,end=60,azimuth_steps=360", cache_dir=str(cache_dir))
    methods, seeds = METHODS[::2], [0, 1]
    serial = run_compare(
        base, tmp_path / "serial", methods=methods, seeds=seeds, sweep=False, workers=1, figures=False
    ).parent
    parallel = run_compare(
        base, tmp_path / "parallel", methods=methods, seeds=seeds, sweep=False, workers=2, figures=False
    ).parent
    _same_files(serial, parallel)
    assert "seeds/seed-1/runs/msa/metrics.json" in stable_content(parallel)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_method_failing_in_a_worker_is_reported_as_in_a_serial_run(short, tmp_path, monkeypatch, workers):
    before_method(monkeypatch, "constant-2m", degenerate)
    out = tmp_path / "cmp"
    with pytest.raises(MethodsFailed) as failed:
        run_compare(short, out, methods=METHODS, sweep=False, workers=workers, figures=False)
    assert failed.value.failed == {"constant-2m": "RuntimeError: degenerate scan statistics"}
    error = (out / "runs" / "constant-2m" / "error.txt").read_text()
    assert error.startswith("Traceback") and "in degenerate" in error and "degenerate scan statistics" in error
    assert sorted(p.name for p in (out / "runs" / "constant-2m").iterdir()) == ["error.txt"]
    for name in ("all", "msa"):
        assert (out / "runs" / name / "metrics.json").is_file()
    report = (out / "report.md").read_text()
    assert "| all |" in report and "| msa |" in report and "| constant-2m |" not in report
    assert "- constant-2m: RuntimeError: degenerate scan statistics (traceback: runs/constant-2m/error.txt)" in report


def test_a_worker_that_dies_fails_its_method_instead_of_the_comparison(short, tmp_path, monkeypatch):
    """A worker killed mid-method (the OOM killer, a crash in a native library) fails the methods it breaks off,
    each with error.txt; the comparison is still written."""
    before_method(monkeypatch, "msa", lambda: os.kill(os.getpid(), signal.SIGKILL))
    out = tmp_path / "cmp"
    with pytest.raises(MethodsFailed) as failed:
        run_compare(short, out, methods=METHODS, sweep=False, workers=2, figures=False)
    assert failed.value.failed["msa"].startswith("BrokenProcessPool")
    assert "terminated abruptly" in (out / "runs" / "msa" / "error.txt").read_text()
    assert (out / "report.md").is_file()


@pytest.mark.parametrize("workers", [0, -2])
def test_workers_below_one_are_refused_before_any_work(base, tmp_path, workers):
    with pytest.raises(InputError, match=f"^--workers must be >= 1, got {workers}$"):
        run_compare(base, tmp_path / "cmp", methods=METHODS, workers=workers)
    assert not (tmp_path / "cmp").exists()
    result = CliRunner().invoke(
        app,
        ["compare", "--dataset", base.dataset, "--workers", str(workers), "--out", str(tmp_path / "cli"), "--quiet"],
    )
    assert isinstance(result.exception, InputError) and "--workers must be >= 1" in str(result.exception)
    assert not (tmp_path / "cli").exists()


def _pools() -> dict[str, int]:
    """A worker's thread pools (threadpoolctl's BLAS and OpenMP libraries, numba) and their thread counts."""
    import numba
    from threadpoolctl import threadpool_info

    return {
        **{f"{p['internal_api']} {p['filepath']}": p["num_threads"] for p in threadpool_info()},
        "numba": numba.get_num_threads(),
    }


def test_workers_run_every_thread_pool_on_one_thread():
    with forked_workers(2, None) as submit:
        pools = submit(_pools).result()
    assert len(pools) > 1 and set(pools.values()) == {1}, pools


# A parent with two workers that print their pids, each then waiting until ended; the parent waits on stdin.
_PARENT = """
import os, signal, sys
from msa_slam.workers import forked_workers

def wait_to_be_ended():
    os.write(1, f"{os.getpid()}\\n".encode())  # one write: the two workers' lines do not interleave
    signal.pause()

with forked_workers(2, None) as submit:
    for _ in range(2):
        submit(wait_to_be_ended)
    sys.stdin.read()
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc")
@pytest.mark.parametrize("stop", [signal.SIGKILL, signal.SIGINT])
def test_workers_end_with_their_parent(stop):
    """kill -9 of the parent (the kernel's parent-death signal) or Ctrl-C (the parent kills them) ends the
    workers mid-job."""
    parent = subprocess.Popen(
        [sys.executable, "-c", _PARENT],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        preexec_fn=terminal_signals,
    )
    workers = [int(parent.stdout.readline()) for _ in range(2)]
    try:
        parent.send_signal(stop)
        parent.wait(timeout=60)
        assert poll(lambda: all(proc_stat(pid) is None for pid in workers), timeout=30), "a worker outlived it"
    finally:
        parent.kill()
        parent.wait()
        parent.stdout.close()
        parent.stdin.close()
        for pid in workers:
            if proc_stat(pid) is not None:
                os.kill(pid, signal.SIGKILL)
