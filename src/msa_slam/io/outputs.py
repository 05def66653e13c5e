"""Result folders that never touch what msa-slam did not write, appear atomically and survive kills.

A result folder is recognised by its marker file (`.msa-slam-result`, JSON: tool, kind, version).
`open_result_folder` runs every check before the long work starts:

- an explicit `--out` that exists and is not a result folder (a file, a dataset, a user's folder with
  anything in it) is refused; an empty folder is taken;
- a previous result folder is replaced only with `overwrite=True` (`resume=True` reuses it in place:
  experiment grids);
- a lock file beside the target (`.NAME.lock`, flock) makes a second run on the same `--out` refuse
  instead of silently losing one result;
- leftovers of a killed run on the same target (`.NAME.partial-*`, `.NAME.old-*`) are removed, and a
  result displaced by a swap that was interrupted is put back.

Without `--out`, results go to `<parent>/<timestamp>` with a `latest` link beside it (as kiss-icp does).
The folder is built under `.NAME.partial-*` and moved into place by one rename, or, over an old result,
by an atomic exchange (Linux renameat2), so a kill at any point leaves either the old or the new result.
Folders get 0777 and files 0666 minus the umask, like any other tool's output.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import msa_slam
from msa_slam.errors import InputError

MARKER = ".msa-slam-result"
DEFAULT_RESULTS = Path("msa_slam_results")  # parent of the default timestamped output folders
LATEST = "latest"
_NO_SPACE = (errno.ENOSPC, errno.EDQUOT)


class OutputError(InputError):
    """An output folder that cannot or must not be written (reported as one line before any work)."""


def current_umask() -> int:
    """The process umask (read by setting and restoring it: the only portable way)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def apply_umask(path: Path) -> None:
    """Give everything under `path` the permissions a plain mkdir/open would have (mkdtemp/mkstemp use 0700/0600)."""
    mask = current_umask()
    paths = [path] + (list(path.rglob("*")) if path.is_dir() else [])
    for p in paths:
        if p.is_symlink():
            continue
        os.chmod(p, (0o777 if p.is_dir() else 0o666) & ~mask)


def is_result_folder(path: Path, kind: str | None = None) -> bool:
    """True when `path` is a folder written by msa-slam (of `kind`, when given)."""
    try:
        meta = json.loads((Path(path) / MARKER).read_text())
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("tool") == "msa-slam" and (kind is None or meta.get("kind") == kind)


def write_marker(folder: Path, kind: str) -> None:
    (Path(folder) / MARKER).write_text(json.dumps({"tool": "msa-slam", "kind": kind,
                                                   "version": msa_slam.__version__}) + "\n")


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap two existing paths (Linux renameat2 RENAME_EXCHANGE); False where unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EPERM, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(a))


def _folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file() and not p.is_symlink())


def disk_full_error(exc: OSError, path: Path, written: Path | None = None) -> OutputError:
    """One line for a full disk: the path, what was written so far (a lower bound of the need), what is free."""
    try:
        free = shutil.disk_usage(path if path.exists() else path.parent).free
    except OSError:
        free = 0
    need = f"; at least {_folder_bytes(written) / 2**20:.1f} MiB needed" if written and written.exists() else ""
    return OutputError(f"{path}: no space left on the device ({free / 2**20:.1f} MiB free{need}); "
                       "free some space or choose another --out")


@contextlib.contextmanager
def staged_dir(target: Path, kind: str | None = None) -> Iterator[Path]:
    """Yield a temporary folder beside `target`; on success it takes `target`'s place in one atomic step.

    For folders msa-slam owns (a result folder already checked by `open_result_folder`, or a cell inside
    an experiment): an existing `target` is replaced. With `kind`, the marker is written first.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=target.parent))
    try:
        if kind is not None:
            write_marker(tmp, kind)
        yield tmp
        apply_umask(tmp)
        if not target.exists() and not target.is_symlink():
            os.replace(tmp, target)
        elif target.is_dir() and not target.is_symlink() and _exchange(tmp, target):
            pass  # tmp now holds the old result, removed below
        else:  # two renames; a kill in between is repaired by `_restore_displaced`
            old = target.parent / f".{target.name}.old-{os.getpid()}-{time.monotonic_ns()}"
            os.replace(target, old)
            os.replace(tmp, target)
            shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:
        if exc.errno in _NO_SPACE:
            raise disk_full_error(exc, target, tmp) from None
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _stale_siblings(target: Path) -> list[Path]:
    parent = target.parent
    if not parent.is_dir():
        return []
    return sorted(list(parent.glob(f".{target.name}.partial-*")) + list(parent.glob(f".{target.name}.old-*")))


def _restore_displaced(target: Path) -> None:
    """Put back a previous result moved aside by a swap that was killed before the new one arrived."""
    if target.exists() or target.is_symlink():
        return
    displaced = [p for p in target.parent.glob(f".{target.name}.old-*") if is_result_folder(p)]
    if displaced:
        os.replace(max(displaced, key=lambda p: p.stat().st_mtime_ns), target)


def clean_stale(target: Path) -> list[Path]:
    """Remove leftovers of killed runs on `target` (call with its lock held); return what was removed."""
    _restore_displaced(target)
    stale = _stale_siblings(target)
    for path in stale:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    return stale


class _Lock:
    """An exclusive, non-blocking flock on `.NAME.lock` beside a target; the file is removed on release."""

    def __init__(self, target: Path) -> None:
        self.path = target.parent / f".{target.name}.lock"
        self.fd: int | None = None

    def acquire(self) -> None:
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise OutputError(f"{self.path.parent / self.path.name[1:-5]}: another msa-slam run is writing "
                                  "this output folder; wait for it or choose another --out") from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:  # not a lock file its previous holder unlinked while we waited to open it
                self.fd = fd
                return
            os.close(fd)

    def release(self) -> None:
        if self.fd is not None:
            with contextlib.suppress(OSError):
                self.path.unlink()
            os.close(self.fd)
            self.fd = None


def _check_target(target: Path, kind: str, overwrite: bool, resume: bool) -> None:
    """Refuse a target that is not ours, or ours but not to be replaced; say what to do instead."""
    if target.is_symlink() and not target.exists():
        raise OutputError(f"--out {target}: a dangling link; choose another --out")
    if not target.exists():
        return
    if not target.is_dir():
        raise OutputError(f"--out {target}: exists and is a file, not a result folder; choose another --out")
    if not any(target.iterdir()):
        return
    if not is_result_folder(target):
        raise OutputError(f"--out {target}: exists and is not a msa-slam result folder (no {MARKER}); "
                          "msa-slam never replaces files it did not write: choose a new or empty folder")
    if resume and is_result_folder(target, kind):
        return
    if not overwrite:
        raise OutputError(f"--out {target}: holds a previous msa-slam result; pass --overwrite to replace it "
                          "or choose another --out")


def _check_writable(folder: Path) -> None:
    """Fail now, not after the work, when the folder that will hold the result cannot be written."""
    probe = folder
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"{folder}: cannot write there ({probe} is not a writable folder)")


def timestamped(parent: Path) -> Path:
    """A new `<parent>/<YYYY-mm-dd_HH-MM-SS>` path (suffixed -2, -3, ... when taken)."""
    stem = time.strftime("%Y-%m-%d_%H-%M-%S")
    candidate, n = parent / stem, 1
    while candidate.exists() or candidate.is_symlink():
        n += 1
        candidate = parent / f"{stem}-{n}"
    return candidate


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


@dataclass
class ResultFolder:
    """A checked, locked output target; `staging()` builds its content and moves it into place."""

    path: Path
    kind: str
    timestamped: bool = False
    _lock: _Lock | None = field(default=None, repr=False)

    @contextlib.contextmanager
    def staging(self) -> Iterator[Path]:
        """A temporary folder (marker written) that replaces `path` atomically when the block succeeds."""
        with staged_dir(self.path, self.kind) as tmp:
            yield tmp
        if self.timestamped:
            point_latest(self.path)

    def prepare_in_place(self) -> Path:
        """Create (or reuse) `path` itself with its marker, for outputs that grow in place (experiment grids)."""
        self.path.mkdir(parents=True, exist_ok=True)
        if not is_result_folder(self.path, self.kind):
            write_marker(self.path, self.kind)
        if self.timestamped:
            point_latest(self.path)
        return self.path


@contextlib.contextmanager
def open_result_folder(out: str | os.PathLike | None, kind: str, default_parent: str | os.PathLike,
                       overwrite: bool = False, resume: bool = False) -> Iterator[ResultFolder]:
    """Check and lock the output of a command before its work starts; release the lock at the end.

    `out=None` picks a new timestamped folder under `default_parent` (and points `latest` at it).
    Raises OutputError (one line) for a target that must not be written.
    """
    if out is None:
        parent = Path(default_parent)
        _check_writable(parent)
        parent.mkdir(parents=True, exist_ok=True)
        folder = ResultFolder(timestamped(parent), kind, timestamped=True)
    else:
        target = Path(out)
        if target.name in ("", ".", "..") or target.is_symlink():  # lock and check the folder itself, not a link
            target = target.resolve()
        folder = ResultFolder(target, kind)
        _check_target(target, kind, overwrite, resume)
        _check_writable(target.parent)
        target.parent.mkdir(parents=True, exist_ok=True)
    lock = _Lock(folder.path)
    try:
        lock.acquire()
    except OSError as exc:
        if isinstance(exc, OutputError):
            raise
        raise OutputError(f"{folder.path}: cannot create the lock file beside it ({exc.strerror})") from None
    folder._lock = lock
    try:
        clean_stale(folder.path)
        if out is not None:  # re-check under the lock: a concurrent run may have finished meanwhile
            _check_target(folder.path, kind, overwrite, resume)
        yield folder
    finally:
        lock.release()
