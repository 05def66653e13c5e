"""Run the msa-slam command line and SIGKILL the process at a chosen file operation (fault injection).

Usage: python fault_driver.py WHERE OCCURRENCE -- msa-slam arguments...
WHERE is where the kill happens, just before the n-th (OCCURRENCE) rename whose destination
- `cache`: lies under the directory given by the MSA_FAULT_CACHE environment variable,
- `staging`: lies inside a result folder being built (`.NAME.partial-*`),
- `final`: is the path given by MSA_FAULT_OUT (the result folder moving into place),
- `inside`: lies inside MSA_FAULT_OUT (cells and tables of an experiment folder that grows in place),
or `none` to run without a kill. Every rename is logged to stdout as `rename <destination>` (for the test's
bookkeeping). A kill by SIGKILL runs no cleanup at all: the harshest interruption there is. The environment
variable MSA_FAULT_SIGNAL names another signal to send instead (SIGHUP: the terminal closed).
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path


def main() -> None:
    where, occurrence = sys.argv[1], int(sys.argv[2])
    args = sys.argv[sys.argv.index("--") + 1 :]
    cache = Path(os.environ.get("MSA_FAULT_CACHE", "/nonexistent")).resolve()
    out = Path(os.environ.get("MSA_FAULT_OUT", "/nonexistent")).resolve()
    kill = signal.Signals[os.environ.get("MSA_FAULT_SIGNAL", "SIGKILL")]
    seen = 0

    def matches(dst: Path) -> bool:
        dst = dst.resolve() if dst.parent.exists() else dst
        if where == "cache":
            return cache in dst.parents
        if where == "staging":
            return any(".partial-" in part for part in dst.parts[:-1])
        if where == "final":
            return dst == out
        if where == "inside":
            return out in dst.parents
        return False

    def check(dst) -> None:
        nonlocal seen
        if matches(Path(os.fsdecode(dst)).absolute()):
            seen += 1
            if seen == occurrence:
                sys.stdout.flush()
                os.kill(os.getpid(), kill)

    real_replace = os.replace

    def replace(src, dst, *a, **k):
        check(dst)
        return real_replace(src, dst, *a, **k)

    os.replace = replace
    import msa_slam.io.staging as staging

    real_exchange = staging._exchange

    def exchange(a, b):
        check(b)
        return real_exchange(a, b)

    staging._exchange = exchange
    from msa_slam.cli import main as cli_main

    sys.argv = ["msa-slam", *args]
    cli_main()


if __name__ == "__main__":
    main()
