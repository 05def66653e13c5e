"""Children of tests that send signals start with the dispositions of a terminal's process: SIGINT and SIGHUP
at their defaults, none blocked. A test run under nohup or as a background job of a script inherits them ignored,
and msa-slam rightly keeps an ignored SIGHUP ignored (nohup), so without this such a run would test its launcher."""

from __future__ import annotations

import signal


def terminal_signals() -> None:
    """subprocess's preexec_fn: SIGINT and SIGHUP to their defaults and an empty signal mask in the child."""
    for stop in (signal.SIGINT, signal.SIGHUP):
        signal.signal(stop, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_SETMASK, [])
