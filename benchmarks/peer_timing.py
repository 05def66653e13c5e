"""End-to-end cost of one SLAM job, msa-slam against the peer, for bench_peer.py's `--speed`: each command runs
as its own process from a cold msa-slam cache (a new, empty cache folder per run; numba's compiled kernels and
the OS page cache stay warm), and its wall time, CPU time (user + system, its reaped worker processes included)
and peak resident memory (the largest of its processes) are read from the kernel's accounting (os.wait4), so
all three systems are measured the same way, scans' reading included.

The three jobs on one simulated KITTI-layout folder: KISS-SLAM (benchmarks/peer_kiss_slam.py, the peer's
default configuration with the given KISS-ICP threads), `msa-slam run --sampler msa --mode realistic` (one SLAM
run) and `msa-slam compare --mode realistic --no-sweep` (the seven methods, worker processes one per CPU). The
repeats alternate the three so that a change of the machine's load touches each alike; the table gives medians.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Timing:
    """One process's cost: wall and CPU seconds, peak RSS in MiB."""

    wall_s: float
    cpu_s: float
    peak_rss_mib: float


def measured(command: list[str], log: Path) -> Timing:
    """Run `command` to its end (stdout and stderr to `log`) and read its cost from the kernel's accounting."""
    with log.open("wb") as sink:
        start = time.perf_counter()
        process = subprocess.Popen(command, stdout=sink, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - start
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode:
        tail = "\n".join(log.read_text(errors="replace").splitlines()[-20:])
        raise RuntimeError(f"{' '.join(command[:4])} ... failed (exit status {process.returncode}):\n{tail}")
    return Timing(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0)


JOBS = {"peer": "KISS-SLAM", "run": "msa-slam run --sampler msa", "compare": "msa-slam compare (7 methods)"}


def jobs(
    folder: Path,
    work: Path,
    cli: str,
    peer_python: str | None,
    driver: Path,
    threads: int,
    chosen: tuple[str, ...] = tuple(JOBS),
) -> dict[str, list[str]]:
    """The `chosen` commands (keys of JOBS) to time on `folder`; outputs and cold caches under `work` (a folder of
    this benchmark's)."""
    msa_slam = [sys.executable, "-c", cli]
    commands = {
        "msa-slam run --sampler msa": [
            *msa_slam,
            "run",
            "-d",
            str(folder),
            "--sampler",
            "msa",
            "--mode",
            "realistic",
            "--out",
            str(work / "run"),
            "--cache-dir",
            str(work / "cache-run"),
            "--quiet",
        ],
        "msa-slam compare (7 methods)": [
            *msa_slam,
            "compare",
            "-d",
            str(folder),
            "--mode",
            "realistic",
            "--no-sweep",
            "--out",
            str(work / "compare"),
            "--cache-dir",
            str(work / "cache-compare"),
            "--quiet",
        ],
    }
    if peer_python is not None:
        commands = {
            "KISS-SLAM": [
                peer_python,
                str(driver),
                "slam",
                str(folder),
                str(work / "peer.npz"),
                "--threads",
                str(threads),
            ],
            **commands,
        }
    return {name: command for name, command in commands.items() if name in {JOBS[job] for job in chosen}}


def timed_jobs(
    folder: Path,
    root: Path,
    cli: str,
    peer_python: str | None,
    driver: Path,
    threads: int,
    repeats: int,
    chosen: tuple[str, ...] = tuple(JOBS),
) -> dict[str, list[Timing]]:
    """Every `chosen` job `repeats` times, alternating, each in a new folder under `root` (so from a cold cache); the
    outputs of the last repeat are kept (root/last) for the accuracy columns."""
    root.mkdir(parents=True, exist_ok=True)
    timings: dict[str, list[Timing]] = {}
    for repeat in range(repeats):
        work = Path(tempfile.mkdtemp(prefix=f"repeat{repeat}-", dir=root))
        for index, (name, command) in enumerate(jobs(folder, work, cli, peer_python, driver, threads, chosen).items()):
            timings.setdefault(name, []).append(measured(command, work / f"job{index}.log"))
            print(f"  {name}, repeat {repeat + 1}/{repeats}: {timings[name][-1].wall_s:.1f} s wall", flush=True)
        last = work
    (root / "last").unlink(missing_ok=True)
    (root / "last").symlink_to(last.name)
    return timings


def median_timing(runs: list[Timing]) -> Timing:
    return Timing(
        statistics.median(t.wall_s for t in runs),
        statistics.median(t.cpu_s for t in runs),
        statistics.median(t.peak_rss_mib for t in runs),
    )
