"""Folders built under a temporary name beside their target and moved into place in one atomic step, with
the marker that identifies msa-slam's results and the clean-up of what a killed run left behind."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import glob
import hashlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Collection, Iterable, Iterator, Mapping

import msa_slam
from msa_slam.errors import InputError

MARKER = ".msa-slam-result"
WRITER = ".msa-slam-writer"  # in a scratch folder: proof that msa-slam made it, flocked while its writer lives
_NO_SPACE = (errno.ENOSPC, errno.EDQUOT)
_CANNOT_WRITE = (errno.EACCES, errno.EPERM, errno.EROFS, errno.EIO)
NEARLY_FULL = 2**20  # bytes free after a write failed without an errno (numpy's tofile): the disk is full


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


def _marker(path: Path) -> dict | None:
    """The marker of a folder msa-slam wrote; None for any other folder."""
    try:
        meta = json.loads((Path(path) / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return meta if isinstance(meta, dict) and meta.get("tool") == "msa-slam" else None


def is_result_folder(path: Path, kind: str | None = None) -> bool:
    """True when `path` is a folder written by msa-slam (of `kind`, when given)."""
    meta = _marker(path)
    return meta is not None and (kind is None or meta.get("kind") == kind)


def result_kind(path: Path) -> str | None:
    """Which command's result `path` holds (its marker's kind: run, online, compare, experiment, sample); None
    for a folder msa-slam did not write."""
    meta = _marker(path)
    return None if meta is None else meta.get("kind")


def write_marker(folder: Path, kind: str, exclude: Collection[str] = (), digests: Mapping[str, str] | None = None
                 ) -> None:
    """Mark `folder` as msa-slam's result of `kind`, listing the files and empty folders in it now (but
    `exclude`) as the ones msa-slam wrote, with a digest of each file: an --overwrite removes nothing else
    (foreign_files) and nothing changed since (edited_files). `digests` keeps the recorded digest of files
    changed since (a resume leaves a user's edit in place and must not take it for msa-slam's content)."""
    folder, exclude, kept = Path(folder), set(exclude), dict(digests or {})
    files = [name for name in _files(folder) if name not in exclude]
    (folder / MARKER).write_text(json.dumps({"tool": "msa-slam", "kind": kind, "version": msa_slam.__version__,
                                             "files": files,
                                             "digests": {name: kept.get(name) or _digest(folder / name)
                                                         for name in files if not name.endswith("/")}}) + "\n")


def recorded_digests(folder: Path) -> dict[str, str]:
    """The digests a result folder's marker records (none for markers of versions without them)."""
    return json.loads((Path(folder) / MARKER).read_text()).get("digests", {})


def listed_files(folder: Path) -> set[str]:
    """The files (and empty folders, ending in /) a result folder's marker lists as msa-slam's."""
    return set(json.loads((Path(folder) / MARKER).read_text()).get("files", []))


def _digest(path: Path) -> str:
    """SHA-256 of a file's bytes, or of a link's target (links are not followed)."""
    if path.is_symlink():
        return hashlib.sha256(os.fsencode(os.readlink(path))).hexdigest()
    with open(path, "rb") as stream:
        return hashlib.file_digest(stream, "sha256").hexdigest()


def edited_files(folder: Path) -> list[str]:
    """Files msa-slam wrote in a result folder (its marker lists them) whose content changed since: a user's
    edits, which --overwrite must not remove. Markers of versions without digests list none."""
    folder = Path(folder)
    digests = recorded_digests(folder)
    present = {name for name in digests if (folder / name).is_symlink() or (folder / name).is_file()}
    return [name for name, digest in sorted(digests.items()) if name in present and _digest(folder / name) != digest]


def foreign_files(folder: Path) -> list[str]:
    """Files and empty folders (relative paths, a folder's ending in /) in a result folder that its marker does
    not list as msa-slam's: someone else put them there, or a run that grows the folder in place was killed
    before listing its own."""
    ours = listed_files(folder)
    return [name for name in _files(Path(folder)) if name not in ours]


def foreign_in_units(folder: Path, units: Iterable[str], edited: bool = False) -> dict[str, list[str]]:
    """Per unit folder (relative to the result `folder`, e.g. cells/<id>), its files the marker does not list as
    msa-slam's (with `edited`, also those changed since msa-slam wrote them): what must stay when the unit is
    rerun and replaced. A unit none of whose files is listed was finished by a killed run before it listed it
    (a unit appears whole, by one rename): all of it is msa-slam's."""
    listed = listed_files(folder)
    others = [*foreign_files(folder), *(edited_files(folder) if edited else [])]
    out = {}
    for unit in units:
        prefix = f"{unit}/"
        ours = any(name.startswith(prefix) for name in listed)
        out[unit] = sorted({name for name in others if name.startswith(prefix)}) if ours else []
    return out


def _files(folder: Path) -> list[str]:
    """Every file and link under `folder` but the marker, and every empty folder (ending in /: a user's, even
    empty, is no more msa-slam's to remove than a file), as sorted relative POSIX paths."""
    names = []
    for p in folder.rglob("*"):
        if p.is_symlink() or not p.is_dir():
            if p.name != MARKER:
                names.append(p.relative_to(folder).as_posix())
        elif not any(p.iterdir()):
            names.append(p.relative_to(folder).as_posix() + "/")
    return sorted(names)


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
    """Bytes in the files under `path` (or in the file `path`)."""
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file() and not p.is_symlink())


def _free_bytes(path: Path) -> int | None:
    """Free space (for this user) on the file system holding `path` or its nearest existing parent."""
    path = Path(path).absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    try:
        return shutil.disk_usage(path).free
    except OSError:
        return None


def disk_full_error(exc: OSError, path: Path, written: Path | None = None,
                    advice: str = "choose another --out") -> OutputError:
    """One line for a full disk: the path, what was written so far (a lower bound of the need), what is free."""
    free = _free_bytes(path) or 0
    need = f"; at least {_folder_bytes(written) / 2**20:.1f} MiB needed" if written and written.exists() else ""
    return OutputError(f"{path}: no space left on the device ({free / 2**20:.1f} MiB free{need}); "
                       f"free some space or {advice}")


def is_disk_full(exc: OSError, path: Path) -> bool:
    """ENOSPC or a quota; or an OSError without errno (numpy's tofile raises one when a write comes up short)
    after which next to nothing is free where `path` lies."""
    if exc.errno in _NO_SPACE:
        return True
    free = _free_bytes(path) if exc.errno is None else None
    return free is not None and free < NEARLY_FULL


def write_error(exc: OSError, path: Path, written: Path | None = None, writing: bool = False,
                advice: str = "choose another --out") -> OutputError | None:
    """The one line for `exc` raised while making `path` (staged in `written`), or None when it is not a
    failed write: a full disk, or a folder that cannot be written (permissions, read-only, I/O error) when the
    error names a file under `path` or `written`. `writing`: the caller only wrote (no input was read), so any
    OSError is a failed write."""
    if is_disk_full(exc, path):
        return disk_full_error(exc, path, written, advice)
    filename = Path(os.fsdecode(exc.filename)).absolute() if exc.filename else None
    inside = filename is not None and any(filename == Path(p).absolute() or Path(p).absolute() in filename.parents
                                          for p in (path, written) if p is not None)
    if writing or (exc.errno in _CANNOT_WRITE and inside):
        what = f"{filename}: " if filename is not None and filename != Path(path).absolute() else ""
        reason = exc.strerror.lower() if exc.strerror else str(exc)
        return OutputError(f"{path}: cannot write there ({what}{reason}); {advice}")
    return None


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
    displaced = [p for p in leftovers(target.parent, target.name, ("old",))
                 if is_result_folder(p) and (abandoned(p) or not (p / WRITER).exists())]
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
