"""The default output of a command without --out: a new `<parent>/<timestamp>` folder claimed under its lock,
with a `latest` link beside it, and the removal of what killed default runs left in `<parent>`."""

from __future__ import annotations

import contextlib
import itertools
import os
import re
import time
from pathlib import Path

from msa_slam.io.output_lock import OutputLock
from msa_slam.io.staging import clean_stale, is_stamp
from msa_slam.io.write_errors import OutputError

DEFAULT_RESULTS = Path("msa_slam_results")  # parent of the default timestamped output folders
LATEST = "latest"


def claim_timestamped(parent: Path) -> tuple[Path, OutputLock]:
    """A new `<parent>/<YYYY-mm-dd_HH-MM-SS>` path (suffixed -2, -3, ... when taken), claimed by taking its
    lock before checking that it is free: two runs started in the same second get two folders, never a
    refusal naming a folder the user did not name."""
    stem = time.strftime("%Y-%m-%d_%H-%M-%S")
    for n in itertools.count(1):
        candidate = parent / (stem if n == 1 else f"{stem}-{n}")
        if candidate.exists() or candidate.is_symlink():
            continue
        lock = OutputLock(candidate)
        with contextlib.suppress(OutputError):  # someone else's file named like its lock: take the next name
            if lock.try_acquire():
                if not (candidate.exists() or candidate.is_symlink()):  # a run that held it may have finished
                    return candidate, lock
                lock.release()
    raise AssertionError("unreachable")


_LEFTOVER = re.compile(r"\.(.+)\.(?:(?:partial|old)-.+|lock)")


def clean_default_parent(parent: Path) -> list[Path]:
    """Remove what killed runs with the default output left in `parent` (each under that folder's lock, when
    no live run holds it): staging folders whose WRITER proves them msa-slam's (staging.clean_stale) and lock
    files holding its stamp. Anything else, a user's file named like them included, stays."""
    names = {m.group(1) for p in parent.iterdir() if (m := _LEFTOVER.fullmatch(p.name))} if parent.is_dir() else set()
    removed = []
    for name in sorted(names):
        lock, target = OutputLock(parent / name), parent / name
        stale_lock = lock.path.is_file() and not lock.path.is_symlink() and is_stamp(_head(lock.path))
        if lock.path.exists() and not stale_lock:
            continue  # not provably msa-slam's lock: leave it (and the folder it would guard) alone
        with contextlib.suppress(OutputError, OSError):
            if lock.try_acquire():
                try:
                    removed += clean_stale(target)
                finally:
                    lock.release()
                removed += [lock.path] if stale_lock else []
    return removed


def _head(path: Path) -> bytes:
    try:
        with open(path, "rb") as stream:
            return stream.read(4096)
    except OSError:
        return b""


def point_latest(folder: Path) -> None:
    """Make `<parent>/latest` a relative link to `folder`, replacing only a link (never a real file)."""
    link = folder.parent / LATEST
    if link.exists() and not link.is_symlink():
        return
    tmp = folder.parent / f".{LATEST}.{os.getpid()}.tmp"
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    os.symlink(folder.name, tmp)
    os.replace(tmp, link)
