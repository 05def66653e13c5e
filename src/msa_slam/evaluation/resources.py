"""Memory and time accounting: bytes of what a stage keeps, peak RSS of the process, wall time per stage.

Per-method memory is the accounted bytes (`array_bytes` and the stores' `nbytes`). Peak RSS is the whole
process's high-water mark since it started: methods run one after another in one process all see the
largest of them (and the front end), so reports print it once, as a process figure (PROCESS_RSS_LABEL).
RSS growth (`current_rss_bytes` at the end of a back-end minus at its start) is per run, and is what the
accounted bytes should explain. glibc's malloc keeps freed heap pages resident between long-lived objects
(GTSAM's Bayes tree is rebuilt piecewise at every update, leaving holes); `release_free_heap` hands them back
(malloc_trim): on two laps of the city tour, RSS at frame 5,000 was 375 MiB with it every 100 frames and
411 MiB without. Both ends of a growth are read after `settle_heap` (garbage collected, free pages handed back): in
`compare`, where methods run one after another in one process, a start read unsettled counted what the
previous method had freed, or left to the cycle collector (its figures), and the next method's growth came out
negative (simulated KITTI-00: constant-1m -116 MiB after all's +350 MiB).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import gc
import os
import resource
import sys
import time
from collections.abc import Iterator

import numpy as np

PROCESS_RSS_LABEL = "process peak RSS (whole process, not this method)"


def array_bytes(*arrays: np.ndarray | None) -> int:
    """Accounted memory of numpy arrays (their data buffers); None entries count as zero."""
    return int(sum(np.asarray(a).nbytes for a in arrays if a is not None))


def peak_rss_bytes() -> int:
    """Peak resident set size of the whole process so far, not of one stage or method (ru_maxrss is KiB on
    Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


def current_rss_bytes() -> int:
    """Resident set size now (Linux /proc/self/statm); the peak where that is unavailable."""
    try:
        with open("/proc/self/statm") as handle:
            return int(handle.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError, AttributeError):
        return peak_rss_bytes()


class _MallInfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


@functools.lru_cache(maxsize=1)
def _glibc() -> ctypes.CDLL | None:
    """The C library when it is glibc (malloc_trim, mallinfo2 exist); None elsewhere."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"))
    except OSError:
        return None
    if not (hasattr(libc, "malloc_trim") and hasattr(libc, "mallinfo2")):  # mallinfo2: glibc >= 2.33
        return None
    libc.mallinfo2.restype = _MallInfo2
    return libc


def release_free_heap() -> None:
    """Return free heap pages to the system (glibc malloc_trim; nothing elsewhere). ~0.1-1 ms."""
    libc = _glibc()
    if libc is not None:
        libc.malloc_trim(0)


def heap_in_use_bytes() -> int | None:
    """Bytes malloc has handed out and not got back (glibc mallinfo2, all arenas); None without glibc.
    Python's small objects (pymalloc arenas) are not in it."""
    libc = _glibc()
    if libc is None:
        return None
    info = libc.mallinfo2()
    return int(info.uordblks + info.hblkhd)


def settle_heap() -> None:
    """Collect cyclic garbage and hand free heap pages back, so an RSS reading taken next is not lowered later
    by memory freed before it (read at both ends of an RSS growth). A full collection: ~7 ms per 100,000
    tracked objects."""
    gc.collect()
    release_free_heap()


def throughput(frames: int, seconds: float, rate_hz: float) -> tuple[float, float]:
    """(frames per second, real-time factor against data recorded at `rate_hz`) of `frames` processed in
    `seconds`: one definition for the online progress line, metrics.json and report.md, so all three agree."""
    fps = frames / seconds if seconds > 0 else float("inf")
    return fps, fps / rate_hz


class StageTimer:
    """Wall time per named stage; a stage entered several times accumulates."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start

    @property
    def total(self) -> float:
        return float(sum(self.seconds.values()))
