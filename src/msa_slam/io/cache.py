"""Cache keys from the identity of the inputs, and cache entries that are checked on read and never break a run.

A key hashes what an entry was computed from: every input file (its path relative to the dataset folder,
its size and modification time, so data replaced in place is a miss and a moved folder a hit), the
effective configuration, and the versions of msa-slam and of the libraries that computed it.
Entries are written under a locked temporary name and renamed; a writer killed before the rename leaves an
unlocked temporary that a later run removes (scratch folders likewise: staging.Writer). A bad entry is
recomputed and a cache that cannot be written is skipped, each with one warning naming the file: a cache only
ever saves time.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import logging
import os
import tempfile
import time
from importlib import metadata
from pathlib import Path
from typing import Any, BinaryIO, Callable, Iterable, Iterator

import numpy as np

import msa_slam
from msa_slam.errors import InputError
from msa_slam.io.staging import (current_umask, is_disk_full, leftovers, new_scratch, remove_abandoned,
                                remove_scratch)

log = logging.getLogger(__name__)

RUN_START_NS = time.time_ns()  # a leftover older than this run and not locked has lost its writer
TEMP_SUFFIX = ".tmp"


def cache_root(cache_dir: str | os.PathLike | None = None) -> Path:
    """`cache_dir`, else $MSA_SLAM_CACHE, else ~/.cache/msa-slam."""
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("MSA_SLAM_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "msa-slam"


def input_identity(files: Iterable[str | os.PathLike], root: str | os.PathLike | None = None) -> list[list]:
    """[name, size, mtime_ns] of every file; the name is relative to `root` when the file is under it, so the
    identity follows the data, not where it is (a moved or copied folder keeps it, files rewritten in place do not)."""
    prefix = None if root is None else os.path.join(os.fspath(root), "")
    out = []
    for file in map(os.fspath, files):
        try:
            st = os.stat(file)
        except OSError as exc:
            raise InputError(f"{file}: cannot read this input file ({exc.strerror})") from None
        name = file[len(prefix):] if prefix and file.startswith(prefix) else os.path.basename(file)
        out.append([name, st.st_size, st.st_mtime_ns])
    return out


def sequence_identity(sequence: Any) -> list[list]:
    """Identity of a ScanSequence's scans (`path`, `scan_files`, and the `selection` within those files a bag
    sequence has: topic, messages), of the files holding their per-point times (`point_time_files`) and of
    their frame times (deskewing uses both; times edited beside the same scans must not reuse the old
    odometry): what odometry and descriptors are computed from."""
    files = [*sequence.scan_files, *getattr(sequence, "point_time_files", ())]
    identity = input_identity(files, sequence.path)
    times = getattr(sequence, "times", None)
    if times is not None:
        digest = hashlib.sha256(np.ascontiguousarray(times, dtype="<f8").tobytes()).hexdigest()
        identity = [*identity, ["times", digest]]
    selection = getattr(sequence, "selection", None)
    return identity if selection is None else [*identity, ["selection", selection]]


def library_versions(names: Iterable[str]) -> dict[str, str | None]:
    """Installed version of each distribution (None when absent)."""
    versions: dict[str, str | None] = {}
    for name in names:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def cache_key(kind: str, inputs: Any, config: Any, libraries: Iterable[str] = ()) -> str:
    """24 hex digits hashing the kind of entry, its inputs' identity, its configuration, msa-slam's version
    and the versions of `libraries`."""
    blob = json.dumps({"kind": kind, "inputs": inputs, "config": config, "msa_slam": msa_slam.__version__,
                       "libraries": library_versions(libraries)}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:24]


@contextlib.contextmanager
def locked_temp(target: Path) -> Iterator[BinaryIO]:
    """A file open for writing under a locked temporary name beside `target`, renamed onto it (0666 minus the
    umask) when the block succeeds and removed otherwise; the lock tells `remove_orphans` its writer is alive."""
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=TEMP_SUFFIX, dir=target.parent)
    tmp, done = Path(name), False
    try:
        with os.fdopen(fd, "wb") as handle:
            fcntl.flock(handle, fcntl.LOCK_EX)
            yield handle
            handle.flush()
            os.fchmod(handle.fileno(), 0o666 & ~current_umask())
            os.replace(tmp, target)
            done = True
    finally:
        if not done:
            with contextlib.suppress(OSError):
                tmp.unlink()


@contextlib.contextmanager
def partial_dir(parent: Path, name: str) -> Iterator[Path]:
    """A scratch folder `.NAME.partial-*` in `parent` for building NAME, marked as msa-slam's and locked while
    this process lives (staging.Writer: a killed one's is removed by `remove_partials`); removed when the block
    ends."""
    tmp, writer = new_scratch(parent, name)
    try:
        yield tmp
    finally:
        remove_scratch(tmp, writer)


def remove_partials(parent: Path, name: str) -> list[Path]:
    """Remove the scratch folders of NAME in `parent` that killed writers left (only those proven msa-slam's,
    their writer dead: staging.abandoned); return them."""
    return remove_abandoned(leftovers(parent, name, ("partial",)))


def _abandoned(path: Path) -> bool:
    """True when the temp file `path` predates this run and no live writer holds its lock."""
    try:
        if path.lstat().st_mtime_ns >= RUN_START_NS:
            return False
        fd = os.open(path, os.O_RDWR | os.O_NOFOLLOW)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(fd)
    except OSError:
        return False  # gone, locked (BlockingIOError) or unreadable: leave it
    return True


def remove_orphans(folder: Path) -> list[Path]:
    """Delete the temporary files (`.*.tmp`, locked_temp's) in the cache folder `folder` that killed writers
    left; return them."""
    try:
        candidates = [p for p in folder.glob(f".*{TEMP_SUFFIX}") if p.is_file() and not p.is_symlink()]
    except OSError:
        return []
    removed = [p for p in candidates if _abandoned(p)]
    for path in removed:
        with contextlib.suppress(OSError):
            path.unlink()
        log.debug("cache: removed %s (left by a writer that was killed)", path)
    return removed


def check_entry(array: np.ndarray, length: int | None = None) -> np.ndarray:
    """`array` if it is a finite float array of `length` rows, else ValueError saying what is wrong."""
    if not np.issubdtype(array.dtype, np.floating) or array.ndim < 1:
        raise ValueError(f"expected a float array, got {array.dtype} of shape {array.shape}")
    if length is not None and len(array) != length:
        raise ValueError(f"{len(array)} rows, expected {length}")
    if not np.isfinite(array).all():
        raise ValueError("NaN or infinite values")
    return array


class CacheDir:
    """A folder of `.npy` entries: reads verified, writes atomic, and any failure only costs the cache.

    Opening it removes temporaries that killed writers left. After one failed write (full disk, read-only,
    no permission) it stops writing, so a run warns once and goes on without a cache.
    """

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.writable = True
        remove_orphans(self.folder)

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.npy"

    def load(self, name: str, check: Callable[[np.ndarray], np.ndarray] = check_entry) -> np.ndarray | None:
        """The entry passed through `check` (which raises ValueError on a bad one), or None when it is absent,
        unreadable, truncated or fails the check (with a warning naming the file: it will be recomputed)."""
        path = self.path(name)
        if not path.is_file():
            return None
        try:
            return check(np.load(path, allow_pickle=False))
        except (OSError, ValueError, EOFError) as exc:
            log.warning("cache: ignoring %s (%s); recomputing it", path, exc)
            return None

    def save(self, name: str, array: np.ndarray) -> Path | None:
        """Write the entry atomically; on failure warn once, stop caching and return None."""
        if not self.writable:
            return None
        path = self.path(name)
        try:
            with locked_temp(path) as handle:
                np.save(handle, array)
        except OSError as exc:
            self.writable = False
            culprit = exc.filename and Path(os.fsdecode(exc.filename)).parent != path.parent  # e.g. a parent folder
            reason = exc.strerror or (os.strerror(errno.ENOSPC) if is_disk_full(exc, path) else exc)
            log.warning("cache: cannot write %s (%s%s; needs %.2f MiB); continuing without the cache", path,
                        f"{os.fsdecode(exc.filename)}: " if culprit else "", reason, array.nbytes / 2**20)
            return None
        return path
