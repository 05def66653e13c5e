"""The marker that identifies msa-slam's result folders (`.msa-slam-result`, JSON: tool, kind, version) and
lists the files msa-slam wrote there with their digests: what an --overwrite may remove, what a user added or
edited."""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Collection, Iterable, Mapping
from pathlib import Path

import msa_slam
from msa_slam.io.digest import file_sha256

MARKER = ".msa-slam-result"


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


def write_marker(
    folder: Path, kind: str, exclude: Collection[str] = (), digests: Mapping[str, str] | None = None
) -> None:
    """Mark `folder` as msa-slam's result of `kind`, listing the files and empty folders in it now (but
    `exclude`) as the ones msa-slam wrote, with a digest of each file: an --overwrite removes nothing else
    (foreign_files) and nothing changed since (edited_files). `digests` keeps the recorded digest of files
    changed since (a resume leaves a user's edit in place and must not take it for msa-slam's content)."""
    folder, exclude, kept = Path(folder), set(exclude), dict(digests or {})
    files = [name for name in _files(folder) if name not in exclude]
    (folder / MARKER).write_text(
        json.dumps(
            {
                "tool": "msa-slam",
                "kind": kind,
                "version": msa_slam.__version__,
                "files": files,
                "digests": {name: kept.get(name) or _digest(folder / name) for name in files if not name.endswith("/")},
            }
        )
        + "\n"
    )


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
    return file_sha256(path)


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
