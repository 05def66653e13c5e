"""Child processes that end with the process that started them, however it ends.

multiprocessing's `daemon` ends a child only when the parent exits normally; a parent killed (kill -9, the OOM
killer) would leave its children working on as orphans: MSA's background compile for minutes, a comparison's
worker processes for the rest of their methods.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1  # prctl option (<linux/prctl.h>): the signal a process gets when its parent dies
_PARENT_POLL_S = 1.0  # where prctl is absent: how often the child checks its parent is alive


def end_with_parent(parent: int) -> None:
    """Make this (child) process end when `parent` does. On Linux the kernel sends SIGKILL on the parent's death
    (prctl; it fires when the thread that started this process ends, so start children from a thread that lives
    as long as they should, such as the main thread); elsewhere a thread watches the parent. The parent may have
    died before either was set up: then this process ends at once."""
    if not _kill_on_parent_death():
        threading.Thread(target=_watch_parent, args=(parent,), daemon=True, name="msa-slam-parent").start()
    if os.getppid() != parent:
        os._exit(0)


def _kill_on_parent_death() -> bool:
    """Ask Linux to SIGKILL this process when its parent dies; False where prctl is not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
    except (OSError, AttributeError):  # no libc, or a libc without prctl
        return False


def _watch_parent(parent: int) -> None:
    """End this process once it is no longer `parent`'s child (an orphan is adopted by another process)."""
    while os.getppid() == parent:
        time.sleep(_PARENT_POLL_S)
    os._exit(0)
