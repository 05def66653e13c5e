"""Folders built under a temporary name beside their target and moved into place in one atomic step, with
the marker that identifies msa-slam's results and the clean-up of what a killed run left behind."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import hashlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Collection, Iterator, Mapping

import msa_slam
from msa_slam.errors import InputError

MARKER = ".msa-slam-result"
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
        if kind is not None:
            write_marker(tmp, kind)  # now listing what the block wrote
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
