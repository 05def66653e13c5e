"""Result folders that never touch what msa-slam did not write, appear atomically and survive kills.

A result folder is recognised by its marker file (`.msa-slam-result`, JSON: tool, kind, version).
`open_result_folder` runs every check before the long work starts:

- an explicit `--out` that exists and is not a result folder (a file, a dataset, a user's folder with
  anything in it) is refused; an empty folder is taken;
- a previous result folder is replaced only with `overwrite=True` (`resume=True` reuses it in place:
  experiment grids, `compare --seeds`), and only when every file (and empty folder) in it is one its marker
  lists as msa-slam's, unchanged since it wrote them (a user's notes or folders, even empty, added to a
  result, or edits to its files, are never removed: the overwrite is refused);
- `--out` expands `~`; the working directory or one of its parents is refused for an output that would take
  its place (not for one that grows in place: an experiment resumed, `report`);
- a lock file beside the target (`.NAME.lock`, flock, holding msa-slam's stamp) makes a second run on the
  same `--out` refuse instead of silently losing one result (checked before the files of a previous result
  are: those of a run writing them now are not reported as a user's);
- leftovers of a killed run on the same target (`.NAME.partial-*`, `.NAME.old-*`, NAME taken literally) are
  removed when their WRITER file proves them msa-slam's and its lock shows their writer dead (never
  anything else), and a result displaced by a swap that was interrupted is put back.

Without `--out`, results go to `<parent>/<timestamp>` with a `latest` link beside it (as kiss-icp does); the
name is claimed under its lock, so two runs started in the same second get `<timestamp>` and
`<timestamp>-2`, and each such run first removes what killed default runs left in `<parent>` (their staging
folders and stamped lock files, as above; anything else stays).
The folder is built under `.NAME.partial-*` and moved into place by one rename, or, over an old result,
by an atomic exchange (Linux renameat2), so a kill at any point leaves either the old or the new result.
Folders get 0777 and files 0666 minus the umask, like any other tool's output.

Here the checks and ResultFolder; the lock is output_lock.py's, the default timestamped folders
default_folders.py's, the marker marker.py's, staging and swaps staging.py's, the one-line write errors
write_errors.py's.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from msa_slam.io.default_folders import DEFAULT_RESULTS, LATEST, claim_timestamped, clean_default_parent, point_latest
from msa_slam.io.marker import (
    MARKER,
    edited_files,
    foreign_files,
    is_result_folder,
    listed_files,
    recorded_digests,
    write_marker,
)
from msa_slam.io.output_lock import OutputLock
from msa_slam.io.staging import clean_stale, discard, staged_dir
from msa_slam.io.write_errors import OutputError, disk_full_error, is_disk_full

__all__ = [
    "DEFAULT_RESULTS",
    "MARKER",
    "OutputError",
    "ResultFolder",
    "claim_timestamped",
    "is_result_folder",
    "open_result_folder",
    "out_path",
    "refuse_working_directory",
    "some_names",
    "staged_dir",
    "write_marker",
]


def _check_target(target: Path, kind: str, overwrite: bool, resume: bool, locked: bool = True) -> None:
    """Refuse a target that is not ours, or ours but not to be replaced; say what to do instead. A previous
    result is looked into only under its lock (`locked`): a run writing it now is then named as such, not by
    the files it has half written."""
    if target.is_symlink() and not target.exists():
        raise OutputError(f"--out {target}: a dangling link; choose another --out")
    if not target.exists():
        return
    if not target.is_dir():
        raise OutputError(f"--out {target}: exists and is a file, not a result folder; choose another --out")
    if not any(target.iterdir()):
        return
    if not is_result_folder(target):
        raise OutputError(
            f"--out {target}: exists and is not a msa-slam result folder (no {MARKER}); "
            "msa-slam never replaces files it did not write: choose a new or empty folder"
        )
    if not locked:
        return
    if overwrite:
        _refuse_foreign(target)
    elif not (resume and is_result_folder(target, kind)):
        raise OutputError(
            f"--out {target}: holds a previous msa-slam result; pass --overwrite to replace it or choose another --out"
        )


def _refuse_foreign(target: Path) -> None:
    """--overwrite replaces a previous result only when all its files are msa-slam's (marker.foreign_files),
    as msa-slam wrote them (marker.edited_files)."""
    foreign = foreign_files(target)
    if foreign:
        raise OutputError(
            f"--out {target}: holds files msa-slam did not write ({some_names(foreign)}); "
            "--overwrite would remove them: move them elsewhere or choose another --out (files of a "
            "killed experiment or `compare --seeds` run count too: rerun it without --overwrite to "
            "finish it first)"
        )
    edited = edited_files(target)
    if edited:
        raise OutputError(
            f"--out {target}: holds files changed since msa-slam wrote them ({some_names(edited)}); "
            "--overwrite would lose the changes: copy them elsewhere or choose another --out (a killed "
            "experiment or `compare --seeds` run leaves its reports so too: rerun it without "
            "--overwrite to finish it first)"
        )


def some_names(names: list[str]) -> str:
    """The first three names, and how many more."""
    more = f" and {len(names) - 3} more" if len(names) > 3 else ""
    return ", ".join(names[:3]) + more


def _check_writable(folder: Path) -> None:
    """Fail now, not after the work, when the folder that will hold the result cannot be written."""
    probe = folder
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"{folder}: cannot write there ({probe} is not a writable folder)")


@dataclass
class ResultFolder:
    """A checked, locked output target; `staging()` builds its content and moves it into place."""

    path: Path
    kind: str
    timestamped: bool = False
    _lock: OutputLock | None = field(default=None, repr=False)
    _not_ours: dict[str, int] = field(default_factory=dict, repr=False)  # growing in place: foreign files, mtimes
    _grows: tuple[str, ...] = field(default=(), repr=False)
    _unit_record: str = field(default="", repr=False)
    _edited: dict[str, tuple[int, str]] = field(default_factory=dict, repr=False)  # in the units: mtime, digest

    @contextlib.contextmanager
    def staging(self) -> Iterator[Path]:
        """A temporary folder (marker written) that replaces `path` atomically when the block succeeds."""
        with staged_dir(self.path, self.kind) as tmp:
            yield tmp
        if self.timestamped:
            point_latest(self.path)

    def prepare_in_place(self, fresh: bool = False, grows: tuple[str, ...] = (), unit_record: str = "") -> Path:
        """Create (or reuse) `path` itself with its marker, for outputs that grow in place (experiment grids,
        `compare --seeds`) in the subfolders `grows`, where msa-slam writes whole folders at a time (units: an
        experiment's cells/<id>, a comparison's seeds/seed-<n>), each holding its `unit_record` file. `fresh`
        (--overwrite, checked: only msa-slam's files) first removes a previous result there, moved aside
        first so a kill leaves the old result (put back by the next run) or none, never half of one. Reused
        (not fresh), a folder whose files outside the units changed since msa-slam wrote them is refused (this
        run rewrites its reports); edits inside the units stay recorded as such (record_files). The files the
        marker does not list are remembered, so that record_files lists them only if this run writes them anew
        (grid.yaml after a killed run) or they make a unit no listed file belongs to (one a killed run
        finished), never someone else's."""
        if fresh and is_result_folder(self.path):
            discard(self.path)
        self.path.mkdir(parents=True, exist_ok=True)
        if not is_result_folder(self.path, self.kind):
            write_marker(self.path, self.kind)
        edited = edited_files(self.path)
        rewritten = [name for name in edited if not any(name.startswith(f"{sub}/") for sub in grows)]
        if rewritten:
            raise OutputError(
                f"--out {self.path}: holds files changed since msa-slam wrote them ({some_names(rewritten)}); "
                "this run would replace them: copy them elsewhere first or choose another --out"
            )
        recorded = recorded_digests(self.path)
        self._edited = {name: ((self.path / name).lstat().st_mtime_ns, recorded[name]) for name in edited}
        self._not_ours = {name: (self.path / name).lstat().st_mtime_ns for name in foreign_files(self.path)}
        self._grows, self._unit_record = grows, unit_record
        if self.timestamped:
            point_latest(self.path)
        return self.path

    def record_files(self) -> None:
        """After a run that grew the folder in place: list its files as msa-slam's in the marker, but the
        unlisted ones it found there and left untouched (prepare_in_place), unless they make a whole unit of
        msa-slam's (with its record file, and no file of it listed before)."""
        listed_units = {self._unit(name) for name in listed_files(self.path)}
        untouched = []
        for name, mtime in self._not_ours.items():
            with contextlib.suppress(FileNotFoundError):  # gone: nothing to list
                if (self.path / name).lstat().st_mtime_ns == mtime and not self._whole_unit(name, listed_units):
                    untouched.append(name)
        kept = {}  # edits inside the units, left in place: recorded as msa-slam wrote them (an --overwrite refuses)
        for name, (mtime, digest) in self._edited.items():
            with contextlib.suppress(FileNotFoundError):
                if (self.path / name).lstat().st_mtime_ns == mtime:
                    kept[name] = digest
        write_marker(self.path, self.kind, exclude=untouched, digests=kept)

    def _unit(self, name: str) -> str | None:
        """The unit folder (`grows`/<unit>) a relative file name lies in, or None."""
        parts = name.split("/")
        return "/".join(parts[:2]) if len(parts) > 2 and parts[0] in self._grows else None

    def _whole_unit(self, name: str, listed_units: set[str | None]) -> bool:
        unit = self._unit(name)
        return (
            unit is not None
            and unit not in listed_units
            and bool(self._unit_record)
            and (self.path / unit / self._unit_record).is_file()
        )


def out_path(out: str | os.PathLike) -> Path:
    """The folder an explicit --out names, `~` expanded (a quoted "~" must not make a folder named ~), and
    named by its own name (`.` or `..` resolved: the temporary folders beside it are named after it)."""
    target = Path(out).expanduser()
    return target.resolve() if target.name in ("", ".", "..") else target


def refuse_working_directory(out: str | os.PathLike) -> None:
    """Refuse an --out that is the working directory or one of its parents, for an output that takes the
    folder's place: replacing it would pull the floor from under the user."""
    try:
        here, there = Path.cwd().resolve(), out_path(out).resolve()
    except (OSError, RuntimeError):  # no working directory, or a loop of links: nothing to compare
        return
    if there == here or there in here.parents:
        what = "the current working directory" if there == here else "a parent of the current working directory"
        raise OutputError(f"--out {out}: is {what}; choose a new folder for the result")


def _out_target(out: str | os.PathLike) -> Path:
    """The folder an explicit --out names (out_path): the folder itself, not a link to it, is locked and checked."""
    target = out_path(out)
    return target.resolve() if target.is_symlink() else target


def _check_output(
    out: str | os.PathLike | None,
    kind: str,
    default_parent: str | os.PathLike,
    overwrite: bool = False,
    resume: bool = False,
) -> None:
    """open_result_folder's checks of `out`, made again under its lock (but the working directory's: an output
    that grows in place (`resume`) may be the folder the user works in, one that replaces it may not)."""
    if out is None:
        _check_writable(Path(default_parent))
        return
    if overwrite or not resume:
        refuse_working_directory(out)
    target = _out_target(out)
    _check_target(target, kind, overwrite, resume, locked=False)
    _check_writable(target.parent)


def _lock_output(out: str | os.PathLike | None, kind: str, parent: Path) -> ResultFolder:
    """The locked folder the result goes to: a new timestamped one under `parent` (whose leftovers of killed
    default runs are removed first), or `out`."""
    try:
        if out is None:
            clean_default_parent(parent)
            path, lock = claim_timestamped(parent)
            return ResultFolder(path, kind, timestamped=True, _lock=lock)
        folder = ResultFolder(_out_target(out), kind)
        lock = OutputLock(folder.path)
        lock.acquire()
        folder._lock = lock
        return folder
    except OSError as exc:
        raise OutputError(f"{parent}: cannot create a lock file there ({exc.strerror or exc})") from None


@contextlib.contextmanager
def open_result_folder(
    out: str | os.PathLike | None,
    kind: str,
    default_parent: str | os.PathLike,
    overwrite: bool = False,
    resume: bool = False,
) -> Iterator[ResultFolder]:
    """Check and lock the output of a command before its work starts; release the lock at the end.

    `out=None` picks a new timestamped folder under `default_parent` (and points `latest` at it).
    Raises OutputError (one line) for a target that must not be written, and for a full disk met while the
    command writes. The folders made to hold the result (`default_parent`, the parents of `out`) are removed
    at the end when the run left them empty.
    """
    _check_output(out, kind, default_parent, overwrite, resume)
    parent = Path(default_parent) if out is None else _out_target(out).parent
    created = _missing_folders(parent)
    parent.mkdir(parents=True, exist_ok=True)
    folder = None
    try:
        folder = _lock_output(out, kind, parent)
        clean_stale(folder.path)
        if out is not None:  # under the lock: a previous result's files, and a concurrent run may have finished
            _check_target(folder.path, kind, overwrite, resume)
        existed = folder.path.exists() or folder.path.is_symlink()
        try:
            yield folder
        except BaseException as exc:
            if not existed:
                _remove_if_bare(folder)
            if isinstance(exc, OSError) and is_disk_full(exc, folder.path):
                raise disk_full_error(exc, folder.path) from None
            raise
    finally:
        if folder is not None and folder._lock is not None:
            folder._lock.release()
        _remove_empty(created)


def _missing_folders(path: Path) -> list[Path]:
    """`path` and those of its ancestors that do not exist yet, deepest first (what mkdir(parents=True) makes)."""
    missing = []
    while not (path.exists() or path.is_symlink()) and path != path.parent:
        missing.append(path)
        path = path.parent
    return missing


def _remove_empty(created: list[Path]) -> None:
    """Remove the folders this run created (`created`, deepest first) and left empty: a run that failed early
    (a bad parameter, a missing input) leaves no empty msa_slam_results/<command>/ behind. A folder holding
    anything (a result, another run's lock file) stays, and with it its parents."""
    for path in created:
        try:
            path.rmdir()
        except OSError:
            return


def _remove_if_bare(folder: ResultFolder) -> None:
    """A folder this run created in place (prepare_in_place) and then failed before writing any file into it
    but the marker (an input error found once the data was open) is removed, with the `latest` link to it:
    nothing half-written stays behind. A folder holding results (finished seeds or cells) is kept to resume."""
    path = folder.path
    if (
        path.is_symlink()
        or not path.is_dir()
        or any(p.name != MARKER and (p.is_symlink() or not p.is_dir()) for p in path.rglob("*"))
    ):
        return
    shutil.rmtree(path)
    link = path.parent / LATEST
    if folder.timestamped and link.is_symlink() and os.readlink(link) == path.name:
        link.unlink()
