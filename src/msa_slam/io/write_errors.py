"""One line for an output that cannot be written: a full disk (what was written so far, what is free) or a
folder without write permission, instead of a traceback after the long work."""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

from msa_slam.errors import InputError

_NO_SPACE = (errno.ENOSPC, errno.EDQUOT)
_CANNOT_WRITE = (errno.EACCES, errno.EPERM, errno.EROFS, errno.EIO)
NEARLY_FULL = 2**20  # bytes free after a write failed without an errno (numpy's tofile): the disk is full


class OutputError(InputError):
    """An output folder that cannot or must not be written (reported as one line before any work)."""


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


def disk_full_error(
    exc: OSError, path: Path, written: Path | None = None, advice: str = "choose another --out"
) -> OutputError:
    """One line for a full disk: the path, what was written so far (a lower bound of the need), what is free."""
    free = _free_bytes(path) or 0
    need = f"; at least {_folder_bytes(written) / 2**20:.1f} MiB needed" if written and written.exists() else ""
    return OutputError(
        f"{path}: no space left on the device ({free / 2**20:.1f} MiB free{need}); free some space or {advice}"
    )


def is_disk_full(exc: OSError, path: Path) -> bool:
    """ENOSPC or a quota; or an OSError without errno (numpy's tofile raises one when a write comes up short)
    after which next to nothing is free where `path` lies."""
    if exc.errno in _NO_SPACE:
        return True
    free = _free_bytes(path) if exc.errno is None else None
    return free is not None and free < NEARLY_FULL


def write_error(
    exc: OSError, path: Path, written: Path | None = None, writing: bool = False, advice: str = "choose another --out"
) -> OutputError | None:
    """The one line for `exc` raised while making `path` (staged in `written`), or None when it is not a
    failed write: a full disk, or a folder that cannot be written (permissions, read-only, I/O error) when the
    error names a file under `path` or `written`. `writing`: the caller only wrote (no input was read), so any
    OSError is a failed write."""
    if is_disk_full(exc, path):
        return disk_full_error(exc, path, written, advice)
    filename = Path(os.fsdecode(exc.filename)).absolute() if exc.filename else None
    inside = filename is not None and any(
        filename == Path(p).absolute() or Path(p).absolute() in filename.parents
        for p in (path, written)
        if p is not None
    )
    if writing or (exc.errno in _CANNOT_WRITE and inside):
        what = f"{filename}: " if filename is not None and filename != Path(path).absolute() else ""
        reason = exc.strerror.lower() if exc.strerror else str(exc)
        return OutputError(f"{path}: cannot write there ({what}{reason}); {advice}")
    return None
