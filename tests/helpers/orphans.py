"""Child processes that must end with their parent: the background side of the orphan tests in test_trust_inputs
and test_compare_workers, and how those tests watch processes."""

from __future__ import annotations

import signal
import time
from collections.abc import Callable
from pathlib import Path

from msa_slam import lifetime


def fallback_child(parent: int, ready: str) -> None:
    """Set up the end-with-parent without prctl (msa_slam.lifetime's portable fallback alone, the thread watching
    the parent, as on a system without prctl), say so by creating the file `ready`, then wait to be ended."""
    lifetime._kill_on_parent_death = lambda: False  # as where prctl is absent
    lifetime._PARENT_POLL_S = 0.05
    lifetime.end_with_parent(parent)
    Path(ready).touch()
    while True:
        signal.pause()


def proc_stat(pid: int) -> list[str] | None:
    """Fields 3 onwards of /proc/PID/stat (state first, nice at index 16); None once the process is gone or is
    a zombie (dead, not yet reaped by whoever adopted it)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None if fields[0] in ("Z", "X") else fields


def poll(condition: Callable[[], bool], timeout: float) -> bool:
    """Whether `condition` holds within `timeout` s, checked every 50 ms."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True
