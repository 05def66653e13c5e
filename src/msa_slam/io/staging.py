"""Folders built under a temporary name beside their target and moved into place in one atomic step, and the
clean-up of what a killed run left behind (proven msa-slam's by its WRITER file). The result marker is
marker.py's, the one-line write errors write_errors.py's."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import glob
import json
import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from msa_slam.io.marker import is_result_folder, write_marker
from msa_slam.io.write_errors import write_error

WRITER = ".msa-slam-writer"  # in a scratch folder: proof that msa-slam made it, flocked while its writer lives


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


def stamp() -> bytes:
    """What msa-slam writes into its lock and WRITER files: proof of authorship a cleaner checks (is_stamp)."""
    return (json.dumps({"tool": "msa-slam", "pid": os.getpid()}) + "\n").encode()


def is_stamp(data: bytes) -> bool:
    try:
        meta = json.loads(data)
    except ValueError:
        return False
    return isinstance(meta, dict) and meta.get("tool") == "msa-slam"


class Writer:
    """The WRITER file of a scratch folder (staging, a displaced old result, a simulation being cast): it
    names msa-slam and is flocked while its process lives, so a later run removes the folder only when it
    can prove both that msa-slam made it and that its writer is gone (`abandoned`)."""

    def __init__(self, folder: Path) -> None:
        self.path = Path(folder) / WRITER
        self.fd: int | None = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX)
            os.write(self.fd, stamp())
        except OSError:
            self.release()
            raise

    def release(self) -> None:
        """Remove the file, then drop its lock (in this order: a cleaner that waited for the lock finds no
        file, so it never takes a folder about to move into place for a leftover). Safe to call twice."""
        if self.fd is not None:
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()
            os.close(self.fd)
            self.fd = None


def new_scratch(parent: Path, name: str, kind: str = "partial") -> tuple[Path, Writer]:
    """A new folder `.NAME.<kind>-*` in `parent`, marked as msa-slam's by its Writer (held until released)."""
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.{kind}-", dir=parent))
    try:
        return tmp, Writer(tmp)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def remove_scratch(folder: Path, writer: Writer | None = None) -> None:
    """Remove a marked scratch folder, if it is still there: its content first and its WRITER last (released
    through `writer` when this process holds it), so that a kill on the way leaves a folder a later run can
    still prove is msa-slam's."""
    if folder.is_dir() and not folder.is_symlink():
        for entry in folder.iterdir():
            if entry.name == WRITER:
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    entry.unlink()
    if writer is not None:
        writer.release()
    else:
        with contextlib.suppress(OSError):
            (folder / WRITER).unlink()
    with contextlib.suppress(OSError):
        folder.rmdir()


def abandoned(path: Path) -> bool:
    """True for a folder msa-slam made (its WRITER file says so) whose writer is gone (nobody holds its lock)."""
    if path.is_symlink() or not path.is_dir():
        return False
    marker = path / WRITER
    try:
        fd = os.open(marker, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return is_stamp(os.read(fd, 4096)) and os.fstat(fd).st_ino == os.stat(marker).st_ino
    except OSError:  # locked (a live writer), or unlinked meanwhile (moved into place)
        return False
    finally:
        os.close(fd)


def leftovers(parent: Path, name: str, kinds: tuple[str, ...] = ("partial", "old")) -> list[Path]:
    """The entries `.NAME.<kind>-*` of `parent`, NAME taken literally (its glob characters escaped: `--out
    "c*"` must never match another run's `.cab.partial-*`)."""
    if not Path(parent).is_dir():
        return []
    return sorted(p for kind in kinds for p in Path(parent).glob(f".{glob.escape(name)}.{kind}-*"))


def remove_abandoned(paths: list[Path]) -> list[Path]:
    """Remove those of `paths` that are `abandoned` (msa-slam's, their writer dead); return them."""
    removed = [path for path in paths if abandoned(path)]
    for path in removed:
        remove_scratch(path)
    return removed


def _displace(target: Path) -> tuple[Path, Writer]:
    """Move a result out of the way (`.NAME.old-*`) and mark it: if a kill comes before it is removed, the
    next run puts it back (target missing) or removes it (`clean_stale`)."""
    old = target.parent / f".{target.name}.old-{os.getpid()}-{time.monotonic_ns()}"
    os.replace(target, old)
    return old, Writer(old)


def discard(target: Path) -> None:
    """Remove a previous result of msa-slam's, moved aside first (_displace) so a kill never leaves half."""
    remove_scratch(*_displace(target))


def _move_into_place(tmp: Path, target: Path) -> None:
    """Put the finished folder `tmp` at `target`, replacing a previous one in one atomic step where possible."""
    if not target.exists() and not target.is_symlink():
        os.replace(tmp, target)
    elif target.is_dir() and not target.is_symlink() and _exchange(tmp, target):
        remove_scratch(tmp, Writer(tmp))  # tmp now holds the old result
    else:  # two renames; a kill in between is repaired by `_restore_displaced`
        old, writer = _displace(target)
        os.replace(tmp, target)
        remove_scratch(old, writer)


@contextlib.contextmanager
def staged_dir(target: Path, kind: str | None = None) -> Iterator[Path]:
    """Yield a temporary folder beside `target`; on success it takes `target`'s place in one atomic step.

    For folders msa-slam owns (a result folder already checked by `open_result_folder`, or a cell inside
    an experiment): an existing `target` is replaced. With `kind`, the marker is written first. The
    temporary folder carries a Writer until it has moved, so a killed run's is removed by the next.
    A failed write (full disk, no permission) is one line (OutputError).
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp, writer = new_scratch(target.parent, target.name)
    try:
        if kind is not None:
            write_marker(tmp, kind, exclude=(WRITER,))
        yield tmp
        if kind is not None:
            write_marker(tmp, kind, exclude=(WRITER,))  # now listing what the block wrote
        apply_umask(tmp)
        _move_into_place(tmp, target)
        writer.path = target / WRITER  # moved with the folder: removed now, or by `clean_stale` after a kill
        writer.release()
    except OSError as exc:
        error = write_error(exc, target, tmp)
        if error is None:
            raise
        raise error from None
    finally:
        remove_scratch(tmp, writer)


def _restore_displaced(target: Path) -> None:
    """Put back a previous result moved aside by a swap that was killed before the new one arrived."""
    if target.exists() or target.is_symlink():
        return
    displaced = [
        p
        for p in leftovers(target.parent, target.name, ("old",))
        if is_result_folder(p) and (abandoned(p) or not (p / WRITER).exists())
    ]
    if displaced:
        newest = max(displaced, key=lambda p: p.stat().st_mtime_ns)
        (newest / WRITER).unlink(missing_ok=True)
        os.replace(newest, target)


def unmark_finished(folder: Path) -> None:
    """Remove the WRITER a run killed just after moving `folder` into place left in it (nothing else)."""
    if abandoned(folder):
        (folder / WRITER).unlink(missing_ok=True)


def clean_stale(target: Path) -> list[Path]:
    """Remove leftovers of killed runs on `target` (call with its lock held): the staging and displaced
    folders that carry msa-slam's WRITER and whose writer is gone, never anything else; return them."""
    _restore_displaced(target)
    unmark_finished(target)
    return remove_abandoned(leftovers(target.parent, target.name))
