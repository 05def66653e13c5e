"""Text scans parsed once per run: a batch run reads every scan for the odometry and again for the descriptors,
then each sampler reads its keyframes' scans once more; a text scan (PCD `DATA ascii`, ASCII PLY) takes
~200 ms to parse against ~1 ms to load as binary, so the first parse is kept as .npy for the run's later reads.

The copies live in a scratch folder of the cache root (`.parsed-scans.run-*`, marked as msa-slam's while its
process lives: io.staging.Writer), removed when the run lets go of its sequence or its process ends; a killed
run's folder is removed by the next batch run. Binary scans are read directly.
"""

from __future__ import annotations

import hashlib
import logging
import os
import weakref
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from msa_slam.io.cache import CacheDir
from msa_slam.io.staging import Writer, leftovers, new_scratch, remove_abandoned, remove_scratch

log = logging.getLogger(__name__)

SCRATCH_NAME = "parsed-scans"
SCRATCH_KIND = "run"
HEADER_BYTES = 65536  # more than any PCD or PLY header the readers accept in practice
TEXT_MARKERS = {".pcd": b"DATA", ".ply": b"FORMAT"}  # the header line naming the encoding, upper-cased

TimedReader = Callable[[Path], tuple[np.ndarray, np.ndarray | None]]


def is_text_scan(path: Path) -> bool:
    """Whether the scan file at `path` stores its points as text (PCD `DATA ascii`, PLY `format ascii`); False
    for other files and for any it cannot tell (the reader then names what is wrong)."""
    marker = TEXT_MARKERS.get(path.suffix.lower())
    if marker is None:
        return False
    try:
        with open(path, "rb") as handle:
            head = handle.read(HEADER_BYTES)
    except OSError:
        return False
    for line in head.splitlines():
        words = line.split()
        if words and words[0].upper() == marker:
            return len(words) > 1 and words[1].lower() == b"ascii"
    return False


class ParsedScans:
    """The run's binary copies of the text scans it parsed, keyed by the scan's absolute path."""

    def __init__(self, root: str | os.PathLike) -> None:
        """Copies go to a new scratch folder of `root` (made on the first text scan); the folders that killed runs
        left there are removed now."""
        self.root = Path(root)
        remove_abandoned(leftovers(self.root, SCRATCH_NAME, (SCRATCH_KIND,)))
        self._store: CacheDir | None = None
        self._failed = False
        self._text: dict[Path, bool] = {}

    def read(self, scan: Path, reader: TimedReader) -> tuple[np.ndarray, np.ndarray | None]:
        """(points, per-point times or None) of `scan`: loaded from this run's copy when it has one, else read
        with `reader` (and a copy kept when the scan is text)."""
        text = self._text.get(scan)
        if text is None:
            text = self._text[scan] = is_text_scan(scan)
        store = self._folder() if text else None
        if store is None:
            return reader(scan)
        name = hashlib.sha256(os.fsencode(os.path.abspath(scan))).hexdigest()[:32]
        kept = _load(store, name)
        if kept is not None:
            return kept
        points, times = reader(scan)
        if times is not None:  # first, so that a copy of the points is never read without its times
            store.save(f"{name}-times", times)
        store.save(f"{name}-points", points)
        return points, times

    def prepare(self, scans: Sequence[Path]) -> None:
        """Make the scratch folder now when any of `scans` is text, so that a reader forked from this process
        (pipeline.read_ahead) keeps its copies where this one reads them and removes them."""
        if any(self._text.setdefault(scan, is_text_scan(scan)) for scan in scans):
            self._folder()

    def _folder(self) -> CacheDir | None:
        """The scratch folder's store, made on first use (None, warned once, when it cannot be)."""
        if self._store is None and not self._failed:
            try:
                self.root.mkdir(parents=True, exist_ok=True)
                folder, writer = new_scratch(self.root, SCRATCH_NAME, SCRATCH_KIND)
            except OSError as exc:
                self._failed = True
                log.warning(
                    "cannot keep parsed scans in %s (%s); text scans are parsed at every read",
                    self.root,
                    exc.strerror or exc,
                )
                return None
            weakref.finalize(self, _remove, folder, writer, os.getpid())
            self._store = CacheDir(folder)
        return self._store


def _load(store: CacheDir, name: str) -> tuple[np.ndarray, np.ndarray | None] | None:
    """A scan's kept copy (points and, when it has them, per-point times), or None when it has none or a bad one."""
    points = store.load(f"{name}-points", _points)
    if points is None or not store.path(f"{name}-times").is_file():
        return None if points is None else (points, None)
    times = store.load(f"{name}-times", _times)
    return None if times is None or len(times) != len(points) else (points, times)


def _remove(folder: Path, writer: Writer, owner: int) -> None:
    """Remove the scratch folder, only in the process that made it (a forked worker shares its copies)."""
    if os.getpid() == owner:
        remove_scratch(folder, writer)


def _points(array: np.ndarray) -> np.ndarray:
    """A CacheDir check: (P, 3) points."""
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"shape {array.shape}, expected (P, 3) points")
    return array


def _times(array: np.ndarray) -> np.ndarray:
    """A CacheDir check: (P,) per-point times."""
    if array.ndim != 1:
        raise ValueError(f"shape {array.shape}, expected (P,) per-point times")
    return array
