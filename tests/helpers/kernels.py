"""The numba kernels the suite calls, compiled once before pytest-xdist's workers start (conftest.py).

numba compiles a kernel on its first call with each argument type and keeps the machine code in its on-disk cache
(beside the module, or in NUMBA_CACHE_DIR). On a fresh clone that cache is empty, and every worker compiled what
it called itself: MSA's kernels alone are one to two minutes of CPU, paid in each worker. Compiled here first, the
workers (and the processes the tests start) load them from the cache instead. The compiled code is the same
either way, so no test sees a difference but its time; with the cache filled, this takes about two seconds of
CPU.
"""

from __future__ import annotations

import numpy as np

from msa_slam.descriptors import make_descriptor
from msa_slam.sampling.msa.eigen import symmetric_eigh
from msa_slam.sampling.msa.warm import compile_kernels

# MSA's settings whose kernels cover every argument type the sampler passes: fast mode's candidate loop on the
# calling thread (windows below fast.PARALLEL_FROM candidates), exact mode's batched terms, its canonical pi and
# the threaded candidate loop of its rounding probes. Window size, pi definition and descriptor shape select code
# at run time, not other compiled versions.
MSA_SETTINGS = ({"mode": "fast", "window": 8}, {"pi": "canonical"})
SCAN_POINTS = 2000  # enough points to fill several Scan Context bins


def compile_test_kernels() -> None:
    """Run each kernel the tests reach once with the argument types they use, so that it is compiled and cached."""
    for params in MSA_SETTINGS:
        compile_kernels(params, (20, 60))
    symmetric_eigh(np.eye(3), np.empty(3), np.empty(3), 3)  # one matrix: the tests' check of the lane solver
    points = np.random.default_rng(0).uniform(-30.0, 30.0, (SCAN_POINTS, 3))
    scan_context = make_descriptor("sc")
    for dtype in (np.float64, np.float32):  # voxel downsampling keeps the points' own type: one version each
        scan_context.compute(points.astype(dtype))
