"""The lock beside an output target (`.NAME.lock`, flock, holding msa-slam's stamp): a second run on the same
--out refuses instead of silently losing one result, and a later run can prove a leftover lock file msa-slam's."""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path

from msa_slam.io.staging import is_stamp, stamp
from msa_slam.io.write_errors import OutputError


class OutputLock:
    """An exclusive, non-blocking flock on `.NAME.lock` beside a target, holding msa-slam's stamp (proof for a
    later run that the file is its own); the file is removed on release."""

    def __init__(self, target: Path) -> None:
        self.path = target.parent / f".{target.name}.lock"
        self.fd: int | None = None

    def try_acquire(self) -> bool:
        """Take the lock; False while another run holds it. A file in the way with content msa-slam did not
        write is refused (an empty one is taken: a run killed before stamping it, or an older version's)."""
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                return False
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if not same:  # a lock file its previous holder unlinked while we waited to open it
                os.close(fd)
                continue
            content = os.pread(fd, 4096, 0)
            if content and not is_stamp(content):
                os.close(fd)
                raise OutputError(
                    f"{self.path}: a file msa-slam did not write is where it keeps its lock; "
                    "move it elsewhere or choose another --out"
                )
            self.fd = fd
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, stamp(), 0)
            except OSError:
                self.release()
                raise
            return True

    def acquire(self) -> None:
        if not self.try_acquire():
            raise OutputError(
                f"{self.path.parent / self.path.name[1:-5]}: another msa-slam run is writing "
                "this output folder; wait for it or choose another --out"
            )

    def release(self) -> None:
        if self.fd is not None:
            with contextlib.suppress(OSError):
                self.path.unlink()
            os.close(self.fd)
            self.fd = None
