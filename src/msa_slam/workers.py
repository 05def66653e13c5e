"""Independent jobs in worker processes forked from this one, so that they share its memory read-only.

compare's methods are each a pure function of one front end (odometry, descriptors and the opened dataset). A
forked worker starts with that front end already in its memory, its pages shared copy-on-write with the parent:
nothing is pickled, read back from the cache or reopened (a bag's index), no module is imported again, and the
scans stay on disk, read lazily by each worker as by the serial path. Spawned workers (multiprocessing's spawn,
or the experiment grid's Dask workers, which suit cells that each build their own front end) would each need the
front end sent to them, the dataset reopened and every library imported anew.

Fork is safe here because every worker is forked at once, by the main thread, before the parent starts a thread
of its own (a progress bar); the back end's threaded libraries either run single-threaded (small_gicp and KISS-ICP
take their thread counts from the configuration, 1 by default) or on a pool that survives a fork (MSA's numba
kernels use numba's workqueue layer, sampling/msa/fast.py); and gc.freeze keeps the workers' garbage collections
from writing to, and so copying, the parent's objects.

Each worker ends with its parent (lifetime.end_with_parent), leaves Ctrl-C to the parent (which kills the
workers, so that the result folder's staging removes what they wrote), and runs its thread pools (BLAS, OpenMP,
numba) on one thread: results then do not depend on thread counts, and N workers keep N cores busy, not more.
"""

from __future__ import annotations

import gc
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from contextlib import contextmanager
from typing import Any

from msa_slam.errors import InputError
from msa_slam.lifetime import end_with_parent

_shared: Any = None  # what the parent shares with the workers it forks (read by `shared`)


def available_cpus() -> int:
    """CPUs this process may run on (its affinity: a job scheduler's allocation, taskset), at least 1."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def check_workers(workers: int) -> int:
    """`workers` when it is a usable number of worker processes; one clear error otherwise."""
    if workers < 1:
        raise InputError(f"--workers must be >= 1, got {workers}")
    return workers


def shared() -> Any:
    """In a worker: the object its parent shares (forked_workers' `shared`)."""
    return _shared


@contextmanager
def forked_workers(workers: int, shared_object: Any) -> Iterator[Callable[..., Future]]:
    """`submit(function, *args)` to `workers` processes forked from this one, which read `shared_object` through
    `shared()`; the first submit forks them all. The function and its arguments and result are pickled (a
    module-level function; small arguments), `shared_object` is not. Leaving by an exception (Ctrl-C, SIGTERM
    through the CLI's handler, a bug) kills the workers at once, whatever they are running."""
    global _shared
    _shared = shared_object
    gc.freeze()
    executor = ProcessPoolExecutor(
        workers, mp_context=multiprocessing.get_context("fork"), initializer=start_worker, initargs=(os.getpid(),)
    )
    try:
        yield executor.submit
    except BaseException:
        _kill(executor)
        executor.shutdown(wait=False, cancel_futures=True)  # the workers are gone: nothing to wait for
        raise
    else:
        executor.shutdown(cancel_futures=True)
    finally:
        gc.unfreeze()
        _shared = None


def _kill(executor: ProcessPoolExecutor) -> None:
    """SIGKILL the executor's workers: its shutdown would wait for the running jobs (a method takes minutes).
    (Its process table is private; Python 3.14 adds ProcessPoolExecutor.kill_workers.)"""
    for process in list((executor._processes or {}).values()):
        process.kill()


def start_worker(parent: int) -> None:
    """A forked worker's set-up (compare's, and the front end's reader: pipeline.forked_ahead): end with `parent`,
    leave Ctrl-C to it, end at once on SIGTERM/SIGHUP where the CLI's handlers (inherited by the fork) would unwind
    the job instead (an ignored SIGHUP, nohup, stays ignored), and one thread per pool."""
    end_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for stop in (signal.SIGTERM, signal.SIGHUP):
        if callable(signal.getsignal(stop)):
            signal.signal(stop, signal.SIG_DFL)
    _one_thread_per_pool()


def _one_thread_per_pool() -> None:
    """BLAS and OpenMP (threadpoolctl) and numba's parallel loops on one thread. numba's thread count changes no
    result (MSA's candidates keep their arithmetic whatever it is: sampling/msa/fast.py), only the load; it is set
    without importing numba, which would then pick its threading layer before MSA's module chose workqueue."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
    numba = sys.modules.get("numba")
    if numba is None:
        os.environ["NUMBA_NUM_THREADS"] = "1"  # read when numba is imported
    else:
        numba.set_num_threads(1)
