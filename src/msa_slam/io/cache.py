"""Cache keys from the identity of the inputs and of the code, and cache entries that are checked on read and
never break a run.

A key hashes what an entry was computed from: every input file (its path relative to the dataset folder and
the SHA-256 of its bytes, so data replaced in place or a copy edited with its times restored is a miss and a
moved folder a hit), the effective configuration, a fingerprint of msa-slam's code that computes the entry
(msa_slam.io.fingerprint) and the versions of the libraries that computed it. File digests are memoised per
absolute path, size, mtime, inode and ctime in the cache folder's DIGESTS_FILE, so a warm run only stats its
inputs. Entries are written under a locked temporary name and renamed; a writer killed before the rename leaves
an unlocked temporary that a later run removes (scratch folders likewise: staging.Writer). A bad entry (unreadable, or not finite float64 of the expected
shape in this machine's byte order) is recomputed and a cache that cannot be written is skipped, each with one
warning naming the file: a cache only ever saves time.
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
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from importlib import metadata
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import numpy as np

from msa_slam.errors import InputError
from msa_slam.io.digest import file_sha256
from msa_slam.io.staging import current_umask, leftovers, new_scratch, remove_abandoned, remove_scratch
from msa_slam.io.write_errors import is_disk_full
from msa_slam.workers import available_cpus

log = logging.getLogger(__name__)

RUN_START_NS = time.time_ns()  # a leftover older than this run and not locked has lost its writer
TEMP_SUFFIX = ".tmp"
DIGESTS_FILE = "input-digests.json"  # in a CacheDir: the memo of its input files' digests (DigestIndex)
_READING_MEMO = threading.Lock()  # held by a DigestIndex reading its file (module-level: an index pickles)
DIGEST_THREADS = 4  # threads hashing input files at most (input_identity); fewer on fewer cores
TIMES_PREFIX = "ms-"  # entry NAME's per-frame compute times are entry ms-NAME (CacheDir.save_times)


class Computed(NamedTuple):
    """A per-frame stage's output for a whole sequence, whether it was replayed from a cache, and the time (ms)
    computing each frame took: measured now, or recorded with the cache entry when it was computed, so that a
    replayed stage still counts what it costs."""

    values: np.ndarray
    cached: bool
    ms: np.ndarray


def cache_root(cache_dir: str | os.PathLike | None = None) -> Path:
    """`cache_dir`, else $MSA_SLAM_CACHE, else ~/.cache/msa-slam."""
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("MSA_SLAM_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "msa-slam"


def pipeline_cache(cache_dir: str | None) -> Path:
    """Folder of the pipeline's caches: <cache root>/pipeline (root: a config's `cache_dir`, $MSA_SLAM_CACHE
    or ~/.cache/msa-slam)."""
    return cache_root(cache_dir) / "pipeline"


def _stamp(path: str) -> list[int]:
    """What changes when a file's bytes may have: size, mtime, inode and ctime (a copy or an edit whose mtime was
    restored still gets another ctime, and a copy another inode)."""
    st = os.stat(path)
    return [st.st_size, st.st_mtime_ns, st.st_ino, st.st_ctime_ns]


def _memo_entry(entry: Any) -> bool:
    """True for a [size, mtime_ns, inode, ctime_ns, sha256] entry of a DigestIndex."""
    return (
        isinstance(entry, list)
        and len(entry) == 5
        and all(type(v) is int for v in entry[:4])
        and isinstance(entry[4], str)
        and len(entry[4]) == 64
    )


class DigestIndex:
    """SHA-256 digests of input files memoised per absolute path and stamp (_stamp) in a JSON file, so that a
    warm run stats its inputs instead of reading them. The file is read on first use; one that is not such an
    index is ignored with a warning and rebuilt. `digest` may be called from several threads (input_identity)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.changed = False  # digests computed since the file was read or written
        self._memo: dict[str, list] | None = None

    def _read(self, warn: bool) -> dict[str, list]:
        try:
            memo = json.loads(self.path.read_bytes())
            if not isinstance(memo, dict) or not all(map(_memo_entry, memo.values())):
                raise ValueError("not an index of file digests")
            return memo
        except FileNotFoundError:
            return {}
        except (OSError, ValueError) as exc:
            if warn:
                log.warning("cache: ignoring %s (%s); rebuilding it", self.path, exc)
            return {}

    def _entries(self) -> dict[str, list]:
        with _READING_MEMO:  # the first callers wait for the one reading the file
            if self._memo is None:
                self._memo = self._read(warn=True)
            return self._memo

    def digest(self, file: str) -> str:
        """SHA-256 of `file`, read only when its stamp is not the memoised one (OSError when it cannot be)."""
        memo, name, stamp = self._entries(), os.path.abspath(file), _stamp(file)
        known = memo.get(name)
        if known is not None and known[:4] == stamp:
            return known[4]
        digest = file_sha256(file)
        if _stamp(file) == stamp:  # unchanged while it was read
            memo[name], self.changed = [*stamp, digest], True
        return digest

    def save(self) -> None:
        """Write the memo atomically, merged with the file as it is now (another process may have added to it)
        and without the files since changed or removed; OSError when it cannot be written."""
        merged = {**self._read(warn=False), **self._entries()}
        current = {}
        for name, entry in merged.items():
            with contextlib.suppress(OSError):
                if _stamp(name) == entry[:4]:
                    current[name] = entry
        with locked_temp(self.path) as handle:
            handle.write(json.dumps(current, sort_keys=True).encode())
        self._memo, self.changed = current, False


def input_identity(
    files: Iterable[str | os.PathLike], root: str | os.PathLike | None = None, cache: CacheDir | None = None
) -> list[list]:
    """[name, SHA-256 of the bytes] of every file (a folder, e.g. a ROS2 bag: of every file below it, named
    FOLDER/PATH); the name is relative to `root` when the file is under it, so the identity follows the data,
    not where it is (a moved or copied folder keeps it, any change to a file's bytes does not). `cache`
    memoises the digests (its DigestIndex, saved here when it grew)."""
    prefix = None if root is None else os.path.join(os.fspath(root), "")
    named = []  # (name in the identity, file)
    for given in (os.fspath(f) for f in files):
        name = given[len(prefix) :] if prefix and given.startswith(prefix) else os.path.basename(given)
        inside = (
            sorted(p.relative_to(given).as_posix() for p in Path(given).rglob("*") if p.is_file())
            if os.path.isdir(given)
            else [""]
        )
        named += [(f"{name}/{part}" if part else name, os.path.join(given, part) if part else given) for part in inside]
    digest = file_sha256 if cache is None else cache.digests.digest
    # hashlib lets go of the GIL while it hashes: a sequence's scans (GBs, before a cold run's odometry can start)
    # are hashed on every core, in about half the time on two
    with ThreadPoolExecutor(min(DIGEST_THREADS, available_cpus(), max(1, len(named)))) as pool:
        digests = pool.map(_digest_of, [digest] * len(named), [file for _, file in named])
        out = [[name, value] for (name, _), value in zip(named, digests)]
    if cache is not None:
        cache.save_digests()
    return out


def _digest_of(digest: Callable[[str], str], file: str) -> str:
    """`digest(file)`; an InputError naming `file` when it cannot be read."""
    try:
        return digest(file)
    except OSError as exc:
        raise InputError(f"{file}: cannot read this input file ({exc.strerror})") from None


def sequence_identity(sequence: Any, cache: CacheDir | None = None) -> list[list]:
    """Identity of a ScanSequence's scans (`path`, `scan_files`, and the `selection` within those files a bag
    sequence has: topic, messages), of the files holding their per-point times (`point_time_files`) and of
    their frame times (deskewing uses both; times edited beside the same scans must not reuse the old
    odometry) and of any correction the reader applies to the points (`correction`): what odometry and
    descriptors are computed from. `cache`: as for input_identity."""
    files = [*sequence.scan_files, *getattr(sequence, "point_time_files", ())]
    identity = input_identity(files, sequence.path, cache)
    times = getattr(sequence, "times", None)
    if times is not None:
        identity = [*identity, ["times", array_sha256(times)]]
    correction = getattr(sequence, "correction", None)  # the reader changes the scans' points (vertical_angle)
    if correction is not None:
        identity = [*identity, ["correction", correction]]
    selection = getattr(sequence, "selection", None)
    return identity if selection is None else [*identity, ["selection", selection]]


def array_sha256(array: np.ndarray) -> str:
    """SHA-256 of an array's values as little-endian float64 (the same on every machine)."""
    return hashlib.sha256(np.ascontiguousarray(array, dtype="<f8").tobytes()).hexdigest()


def named_files(value: Any) -> list[str]:
    """The existing files a configuration names: its string values (nested in mappings and lists too) that are
    paths of files, e.g. network weights or a pose file, whose content is then part of a key."""
    if isinstance(value, dict):
        return [file for item in value.values() for file in named_files(item)]
    if isinstance(value, (list, tuple)):
        return [file for item in value for file in named_files(item)]
    return [os.fspath(value)] if isinstance(value, (str, os.PathLike)) and os.path.isfile(value) else []


def sequence_inputs(sequence: Any, files: Iterable[str | os.PathLike] = (), cache: CacheDir | None = None) -> dict:
    """The inputs part of the key of an entry computed from `sequence` and `files` (e.g. weights, a pose file)."""
    return {"scans": sequence_identity(sequence, cache), "files": input_identity(files, cache=cache)}


def library_versions(names: Iterable[str]) -> dict[str, str | None]:
    """Installed version of each distribution (None when absent)."""
    versions: dict[str, str | None] = {}
    for name in names:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def cache_key(kind: str, inputs: Any, config: Any, code: str, libraries: Iterable[str] = ()) -> str:
    """24 hex digits hashing the kind of entry, its inputs' identity, its configuration, the fingerprint `code` of
    msa-slam's code that computes it (msa_slam.io.fingerprint.code_fingerprint) and the versions of `libraries`."""
    blob = json.dumps(
        {"kind": kind, "inputs": inputs, "config": config, "code": code, "libraries": library_versions(libraries)},
        sort_keys=True,
        default=str,
    )
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


def check_entry(array: np.ndarray, shape: tuple[int | None, ...]) -> np.ndarray:
    """`array` if it holds finite float64 values in this machine's byte order, in C order, of `shape` (None: any
    size along that axis), else ValueError saying what is wrong: an entry of another precision, byte order or
    layout would change the results' bytes, and one of another shape would fail the run far from the cache."""
    expected = np.dtype(np.float64)
    if array.dtype != expected:
        raise ValueError(f"dtype {array.dtype.str}, expected {expected.str} (float64 in this machine's byte order)")
    if array.ndim != len(shape) or any(want is not None and got != want for got, want in zip(array.shape, shape)):
        wanted = ", ".join("N" if n is None else str(n) for n in shape)
        raise ValueError(f"shape {array.shape}, expected ({wanted}{',' if len(shape) == 1 else ''})")
    if not array.flags.c_contiguous:
        raise ValueError("stored in Fortran order, expected C order")
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
        self.digests = DigestIndex(self.folder / DIGESTS_FILE)
        remove_orphans(self.folder)

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.npy"

    def load(self, name: str, check: Callable[[np.ndarray], np.ndarray], mapped: bool = False) -> np.ndarray | None:
        """The entry passed through `check` (which raises ValueError on a bad one), or None when it is absent,
        unreadable, truncated or fails the check (with a warning naming the file: it will be recomputed).
        `mapped`: memory-mapped read-only (a large entry of which a run reads only parts)."""
        path = self.path(name)
        if not path.is_file():
            return None
        try:
            return check(np.load(path, allow_pickle=False, mmap_mode="r" if mapped else None))
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
            self._unwritable(path, exc, f"; needs {array.nbytes / 2**20:.2f} MiB")
            return None
        return path

    def save_times(self, name: str, ms: np.ndarray) -> None:
        """Record beside entry `name` what computing each of its frames took (ms); call it before saving the entry,
        so that an entry is never found without its times."""
        self.save(f"{TIMES_PREFIX}{name}", np.asarray(ms, dtype=np.float64))

    def load_times(self, name: str, frames: int) -> np.ndarray | None:
        """The per-frame compute times (ms) recorded with entry `name`, or None when absent or bad (an entry
        without them is recomputed: a replayed stage must count the time it took)."""

        def check(ms: np.ndarray) -> np.ndarray:
            if (check_entry(ms, (frames,)) < 0).any():
                raise ValueError("negative times")
            return ms

        return self.load(f"{TIMES_PREFIX}{name}", check)

    def save_digests(self) -> None:
        """Record the input digests computed since the last save (see DigestIndex); a failure costs the memo only
        and, like a failed entry, stops the caching with one warning."""
        if self.writable and self.digests.changed:
            try:
                self.digests.save()
            except OSError as exc:
                self._unwritable(self.digests.path, exc)

    def _unwritable(self, path: Path, exc: OSError, needs: str = "") -> None:
        """Stop writing after a failure to write `path`, with one warning naming it (or the parent folder that
        failed) and the reason."""
        self.writable = False
        culprit = exc.filename and Path(os.fsdecode(exc.filename)).parent != path.parent  # e.g. a parent folder
        reason = exc.strerror or (os.strerror(errno.ENOSPC) if is_disk_full(exc, path) else exc)
        log.warning(
            "cache: cannot write %s (%s%s%s); continuing without the cache",
            path,
            f"{os.fsdecode(exc.filename)}: " if culprit else "",
            reason,
            needs,
        )
