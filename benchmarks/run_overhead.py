"""What a cold `msa-slam run` does on the odometry's critical path besides KISS-ICP, per frame and once, on a
KITTI-layout folder (e.g. one `msa-slam simulate --trajectory kitti-07 --end 300` wrote): the consumer's time to
receive a frame from the forked reader (the reader far ahead: the consumer works 30 ms a frame, as KISS-ICP does),
counting a scan's points in range, and hashing the folder's files serially and as input_identity does.
Not in `make bench` (it needs such a folder). docs/performance.md records its figures.

    python benchmarks/run_overhead.py FOLDER [--frames 140]
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ThreadPoolExecutor
from itertools import islice
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from msa_slam.descriptors import make_descriptor
from msa_slam.io.cache import DIGEST_THREADS
from msa_slam.io.digest import file_sha256
from msa_slam.odometry import KissOdometry
from msa_slam.pipeline.config import make_config
from msa_slam.pipeline.forked_ahead import forked_ahead
from msa_slam.pipeline.read_ahead import ReadAhead
from msa_slam.sources import open_sequence
from msa_slam.types import as_points

WORK_S = 0.03  # the consumer's work a frame, so that the reader gets ahead


def _ms(values: list[float]) -> str:
    return f"median {np.median(values) * 1e3:.3f} ms (mean {np.mean(values) * 1e3:.3f})"


def receive(folder: str, frames: int) -> None:
    """Time in next() of forked_ahead over the run's reader items (wall and the consumer thread's CPU)."""
    config = make_config(dataset=folder, sampler="msa")
    sequence = open_sequence(config.dataset, source=config.source)
    reader = ReadAhead(sequence, make_descriptor(config.descriptor), voxel_size=config.verifier.voxel_size)
    items = list(islice(reader._computed(), 10))
    busy = np.random.default_rng(0).random((200, 200))
    wall, cpu = [], []
    received = iter(forked_ahead((items[i % len(items)] for i in range(frames)), 4))
    for i in range(frames):
        w, c = time.perf_counter(), time.thread_time()
        next(received)
        if i >= 10:  # the reader has got ahead
            wall.append(time.perf_counter() - w)
            cpu.append(time.thread_time() - c)
        end = time.perf_counter() + WORK_S
        while time.perf_counter() < end:
            busy @ busy
    print(f"receiving a frame: wall {_ms(wall)}; consumer CPU {_ms(cpu)}")
    cloud = as_points(items[0][0].points)
    odometry = KissOdometry()
    times = []
    for _ in range(200):
        c = time.thread_time()
        odometry._registrable(cloud)
        times.append(time.thread_time() - c)
    print(f"counting {len(cloud)} points in range: CPU {_ms(times)}")


def digests(folder: str) -> None:
    files = sorted(str(p) for p in Path(folder).rglob("*") if p.is_file())
    for _ in range(3):
        w = time.perf_counter()
        serial = [file_sha256(f) for f in files]
        s = time.perf_counter() - w
        w = time.perf_counter()
        with ThreadPoolExecutor(min(DIGEST_THREADS, os.cpu_count() or 1)) as pool:
            threaded = list(pool.map(file_sha256, files))
        assert serial == threaded
        print(f"hashing {len(files)} files: serial {s:.3f} s, threads {time.perf_counter() - w:.3f} s (wall)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    parser.add_argument("--frames", type=int, default=140)
    args = parser.parse_args()
    with threadpool_limits(limits=1):  # the consumer's stand-in work on one core, as KISS-ICP's one thread
        receive(args.folder, args.frames)
    digests(args.folder)


if __name__ == "__main__":
    main()
