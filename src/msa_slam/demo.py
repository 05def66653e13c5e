"""The demo (the README's main job): the paper's sampler comparison on the embedded simulated sequence.

`sim:demo` is the simulator's default: the whole KITTI-06 trajectory at the native 10 Hz (1101 scans)
with a 64 x 720 HDL-64 and the calibrated `kitti` realism preset. It is simulated, run through KISS-ICP and
described (Scan Context) on first use and cached, so later runs only redo the back-end per sampler. Meanwhile
MSA's numba kernels compile on the other core (the cached front end starts that: pipeline.frontend); the methods
then run in one worker process per CPU, as `compare` runs them (the same files as one after another).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from msa_slam.experiments.compare import run_compare
from msa_slam.io.outputs import DEFAULT_RESULTS
from msa_slam.pipeline.config import make_config
from msa_slam.workers import available_cpus

DEMO_DATASET = "sim:demo"


def run_demo(
    out: str | os.PathLike | None = None,
    cache_dir: str | os.PathLike | None = None,
    quiet: bool = False,
    overwrite: bool = False,
) -> Path:
    """Run the comparison with the paper's settings (KISS-ICP, Scan Context, oracle loops); return report.md.

    `out=None` writes a new timestamped folder under msa_slam_results/demo (linked as `latest`). The threshold
    sweep is left out (it would add about half to the methods' time); `msa-slam compare -d sim:demo` runs it."""
    start = time.perf_counter()
    config = make_config(
        dataset=DEMO_DATASET,
        odometry="kiss",
        descriptor="sc",
        mode="oracle",
        cache_dir=None if cache_dir is None else str(cache_dir),
    )
    report = run_compare(
        config,
        out,
        quiet=quiet,
        overwrite=overwrite,
        default_parent=DEFAULT_RESULTS / "demo",
        sweep=False,
        workers=available_cpus(),
    )
    if not quiet:
        print(f"demo finished in {time.perf_counter() - start:.0f} s")
    return report
