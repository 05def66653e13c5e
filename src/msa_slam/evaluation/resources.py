"""Memory and time accounting: bytes of what a stage keeps, peak RSS of the process, wall time per stage.

Per-method memory is the accounted bytes (`array_bytes` and the stores' `nbytes`). Peak RSS is the whole
process's high-water mark since it started: methods run one after another in one process all see the
largest of them (and the front end), so reports print it once, as a process figure (PROCESS_RSS_LABEL).
RSS growth (`current_rss_bytes` at the end of a back-end minus at its start) is per run, and is what the
accounted bytes should explain.
"""

from __future__ import annotations

import contextlib
import os
import resource
import sys
import time
from typing import Iterator

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
