"""Cost of deterministic odometry: KISS-ICP frames per second with 1 thread (msa-slam's default, identical
runs give identical poses) against KISS-ICP's own default of all cores (num_threads=0).

KISS-ICP fixes its thread count once per process, so every run is a fresh process. Scans are read into
memory first, so only registration is timed. Reports medians over --repeats runs and whether the repeated
runs of each setting gave bitwise-identical poses.

    python benchmarks/bench_odometry.py [--dataset sim:test] [--repeats 3] [--threads 1 0]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def one_run(dataset: str, num_threads: int, cache_dir: str | None, out: Path) -> None:
    """Register every scan of `dataset` with a fresh KISS-ICP; save the poses and the seconds to `out`."""
    from msa_slam.odometry import KissOdometry
    from msa_slam.sources import open_sequence

    scans = [frame.points for frame in open_sequence(dataset, cache_dir=cache_dir)]
    odometry = KissOdometry(num_threads=num_threads)
    start = time.perf_counter()
    poses = np.stack([odometry.register(points) for points in scans])
    np.savez(out, poses=poses, seconds=time.perf_counter() - start)


def timed_runs(args: argparse.Namespace, folder: Path) -> dict[int, list[tuple[float, np.ndarray]]]:
    """(seconds, poses) of --repeats runs per thread setting, interleaved so load changes hit all settings."""
    runs: dict[int, list[tuple[float, np.ndarray]]] = {threads: [] for threads in args.threads}
    for k in range(args.repeats):
        for threads in args.threads:
            out = folder / f"threads{threads}_{k}.npz"
            command = [sys.executable, __file__, "--dataset", args.dataset, "--one", str(threads), str(out)]
            subprocess.run(command + (["--cache-dir", args.cache_dir] if args.cache_dir else []), check=True)
            with np.load(out) as data:
                runs[threads].append((float(data["seconds"]), data["poses"]))
    return runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="sim:test")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--threads", type=int, nargs="+", default=[1, 0], help="KISS-ICP num_threads settings to compare (0: all cores)"
    )
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("--one", nargs=2, metavar=("THREADS", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        one_run(args.dataset, int(args.one[0]), args.cache_dir, Path(args.one[1]))
        return

    print(f"dataset {args.dataset}: medians over {args.repeats} runs (one process each)\n")
    print("num_threads | frames/s | s/run | runs bitwise identical | max |pose diff| to the first setting")
    print("---|---|---|---|---")
    with tempfile.TemporaryDirectory() as tmp:
        all_runs = timed_runs(args, Path(tmp))
    reference = all_runs[args.threads[0]][0][1]
    for threads, runs in all_runs.items():
        seconds = statistics.median(s for s, _ in runs)
        identical = all(np.array_equal(runs[0][1], poses) for _, poses in runs[1:])
        diff = max(float(np.abs(poses - reference).max()) for _, poses in runs)
        print(
            f"{threads} | {len(reference) / seconds:.1f} | {seconds:.2f} | {'yes' if identical else 'no'} | {diff:.1e}"
        )


if __name__ == "__main__":
    main()
