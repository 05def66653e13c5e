"""The numba kernels the suite calls, compiled once before pytest-xdist's workers run their first test (conftest.py).

numba compiles a kernel on its first call with each argument type and keeps the machine code in its on-disk cache
(beside the module, or in NUMBA_CACHE_DIR). On a fresh clone that cache is empty, and every worker compiled what
it called itself: MSA's kernels alone are one to two minutes of CPU, paid in each worker. Compiled here first, the
workers (and the processes the tests start) load them from the cache instead. The compiled code is the same
either way, so no test sees a difference but its time; with the cache filled, this takes about two seconds of
CPU.

The kernels compile in two processes at once, one a core of the two-core machine, while the workers start and
collect the tests: in one process exact mode with canonical pi (its threaded candidate loop alone is about a third
of the whole), in the other the rest. Both compile the kernels the two modes share unless the other has already
cached them (numba looks in its cache before compiling each kernel): CPU the other core would otherwise spend
idle.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import Future, ProcessPoolExecutor

import numpy as np

from helpers.msa_windows import planar_window
from msa_slam.datasets.lzf import lzf_decompress
from msa_slam.descriptors import make_descriptor
from msa_slam.odometry.deskew import deskew
from msa_slam.sampling.msa import exact, fast
from msa_slam.sampling.msa.eigen import symmetric_eigh
from msa_slam.sampling.msa.warm import compile_kernels

# MSA's settings whose kernels cover every argument type the sampler passes: fast mode's candidate loop on the
# calling thread (windows below fast.PARALLEL_FROM candidates), exact mode's batched terms, its canonical pi and
# the threaded candidate loop of its rounding probes. Window size, pi definition and descriptor shape select code
# at run time, not other compiled versions.
FAST = {"mode": "fast", "window": 8}
EXACT_CANONICAL = {"pi": "canonical"}
SHAPE = (20, 60)
SCAN_POINTS = 2000  # enough points to fill several Scan Context bins


def compile_exact_canonical() -> None:
    """Exact mode with canonical pi: the longest chain of kernels, each compiled after those it calls."""
    compile_kernels(EXACT_CANONICAL, SHAPE)


def compile_the_rest() -> None:
    """Every other kernel the tests reach, with the argument types they pass: those the modes do not share first,
    so that exact mode's process has cached some of the shared ones by the time fast mode needs them."""
    scan = np.random.default_rng(0).uniform(-30.0, 30.0, (SCAN_POINTS, 4))
    xyz = scan[:, :3].copy()
    scan_context = make_descriptor("sc")
    # Voxel downsampling keeps the points' type and memory layout, one compiled version each: (P, 3) clouds and
    # (P, 4) scans (their first three columns) in float64 and float32, and float32 clouds in Fortran order
    for cloud in (xyz, scan, xyz.astype(np.float32), scan.astype(np.float32), np.asfortranarray(xyz, np.float32)):
        scan_context.compute(cloud)
    symmetric_eigh(np.eye(3), np.empty(3), np.empty(3), 3)  # one matrix: the tests' check of the lane solver
    deskew(xyz, np.linspace(0.0, 1.0, SCAN_POINTS), np.ones(3), np.array([0.0, 0.0, 0.1]))
    lzf_decompress(b"\x02abc", 3)  # one literal run of three bytes
    compile_kernels(FAST, SHAPE)
    # test_msa_canonical.py checks the candidate loop against one candidate at a time: the loop passes a literal
    # False for `canonical`, the test a bool, a version of its own
    t, descriptors = planar_window()
    dist, _ = exact.pairwise(t, descriptors)
    scratch = np.empty(fast.scratch_size(len(t)))
    fast.information_gram(np.arange(3), 3, dist, fast.gram(descriptors), scratch, 0, True)


KERNEL_SETS = (compile_exact_canonical, compile_the_rest)


class KernelCompilation:
    """KERNEL_SETS compiling, each in a spawned process of its own (started on construction)."""

    def __init__(self) -> None:
        self._pool = ProcessPoolExecutor(max_workers=len(KERNEL_SETS), mp_context=multiprocessing.get_context("spawn"))
        self._running: list[Future] = [self._pool.submit(compile_set) for compile_set in KERNEL_SETS]

    def wait(self) -> None:
        """Return once every set is compiled (at once when they already are); a failed set's error is raised."""
        try:
            for compiling in self._running:
                compiling.result()
        finally:
            self._pool.shutdown()
