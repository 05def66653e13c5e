"""Keyframe clouds on disk: one downsampled .npy per keyframe, memory-mapped when verification reads it.

Same interface as KeyframeCloudStore (add / [] / in / len / nbytes), so long runs
keep only the keyframe bookkeeping in RAM; `nbytes` is what sits in RAM (zero for clouds on disk) and
`disk_bytes` what the files hold.

The files go to a private folder `msa-kf-clouds-<pid>-<random>` under `store_dir` (the system temporary
folder by default), so two runs never share files; it carries msa-slam's WRITER file (io.staging), locked
while its process lives. It is removed on close (and at interpreter exit if never closed); a folder left by a
killed run is removed by the next store opened in the same place (or the next run of an experiment) once its
process is gone. Nothing else in `store_dir` is touched; `store_dir` itself is removed only if the
store created it and it is empty at close.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import weakref
from collections.abc import Hashable
from pathlib import Path

import numpy as np

from msa_slam.errors import InputError
from msa_slam.io.atomic import atomic_path
from msa_slam.io.staging import WRITER, Writer, abandoned, remove_scratch
from msa_slam.registration.clouds import KeyframeCloudStore, downsample

PREFIX = "msa-kf-clouds-"
_OWNED = re.compile(re.escape(PREFIX) + r"(\d+)-[^/]+")
_STORE_FILE = re.compile(r"kf_.+\.npy|\.kf_.+\.npy\..+\.tmp")  # clouds and atomic_path's partial files


def process_alive(pid: int) -> bool:
    """Whether process `pid` exists (signal 0 checks without sending; another user's process counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_stores(parent: Path) -> list[Path]:
    """Remove the store folders in `parent` left by runs whose process is gone; return them.

    Only folders named by this module, owned by this user and holding nothing but cloud files qualify, and
    only once their WRITER's lock is free (folders of versions without one: once their process is gone).
    """
    if not parent.is_dir():
        return []
    removed = []
    for path in parent.iterdir():
        match = _OWNED.fullmatch(path.name)
        if match is None or path.is_symlink() or not path.is_dir():
            continue
        try:
            if path.stat().st_uid != os.getuid() or not all(
                _STORE_FILE.fullmatch(f.name) or f.name == WRITER for f in path.iterdir()
            ):
                continue
            marked = (path / WRITER).exists()
            if (marked and not abandoned(path)) or (not marked and process_alive(int(match.group(1)))):
                continue
            shutil.rmtree(path)
        except OSError:  # removed meanwhile by another run, or not ours to remove
            continue
        removed.append(path)
    return removed


def _remove_store(folder: Path, writer: Writer, created: list[Path], owner: int) -> None:
    """Remove the store's folder, then the folders made for it (deepest first) while they are empty;
    only in the process that made them (a forked child's copy of the store must not delete them)."""
    if os.getpid() != owner:
        return
    remove_scratch(folder, writer)
    for path in created:
        try:
            path.rmdir()  # fails if not empty: never removes what someone else put there meanwhile
        except OSError:
            return


class DiskCloudStore:
    """Downsampled keyframe clouds as `<private folder>/kf_<key>.npy` under `store_dir` (temp folder if None)."""

    def __init__(self, voxel_size: float = 0.5, store_dir: str | os.PathLike | None = None) -> None:
        if not voxel_size > 0:
            raise InputError(f"voxel_size must be > 0, got {voxel_size}")
        self.voxel_size = float(voxel_size)
        parent = Path(store_dir if store_dir is not None else tempfile.gettempdir()).absolute()
        if parent.exists() and not parent.is_dir():
            raise InputError(f"store_dir {str(parent)!r} is a file; give a folder for the keyframe clouds")
        created = [p for p in (parent, *parent.parents) if not p.exists()]  # deepest first
        parent.mkdir(parents=True, exist_ok=True)
        remove_stale_stores(parent)
        self.folder = Path(tempfile.mkdtemp(prefix=f"{PREFIX}{os.getpid()}-", dir=parent))
        writer = Writer(self.folder)
        self._sizes: dict[Hashable, int] = {}
        self._cleanup = weakref.finalize(self, _remove_store, self.folder, writer, created, os.getpid())

    def _path(self, key: Hashable) -> Path:
        return self.folder / f"kf_{key}.npy"

    def add(self, key: Hashable, points: np.ndarray) -> np.ndarray:
        """Downsample `points`, write them under `key`; return the cloud (not kept in RAM)."""
        return self.keep(key, downsample(points, self.voxel_size, where=f"keyframe {key}"))

    def keep(self, key: Hashable, cloud: np.ndarray) -> np.ndarray:
        """Write `cloud`, already downsampled at this store's voxel size (cloud_cache.FrameClouds), under `key`."""
        with atomic_path(self._path(key)) as tmp, open(tmp, "wb") as handle:
            np.save(handle, cloud)
        self._sizes[key] = int(cloud.nbytes)
        return cloud

    def __getitem__(self, key: Hashable) -> np.ndarray:
        if key not in self._sizes:
            raise InputError(f"keyframe {key!r} has no stored cloud")
        return np.load(self._path(key), mmap_mode="r")

    def __contains__(self, key: Hashable) -> bool:
        return key in self._sizes

    def __len__(self) -> int:
        return len(self._sizes)

    @property
    def nbytes(self) -> int:
        """Bytes held in RAM for the clouds: none (they are read from disk on demand)."""
        return 0

    @property
    def disk_bytes(self) -> int:
        """Bytes of point data on disk."""
        return int(sum(self._sizes.values()))

    def close(self) -> None:
        """Remove the clouds' folder (and `store_dir` if the store created it and nothing else is there)."""
        self._cleanup()
        self._sizes.clear()


def make_cloud_store(kind: str, voxel_size: float, store_dir: str | os.PathLike | None = None):
    """`memory`: KeyframeCloudStore in RAM; `disk`: DiskCloudStore under `store_dir` (temporary if None)."""
    if kind == "memory":
        return KeyframeCloudStore(voxel_size)
    if kind == "disk":
        return DiskCloudStore(voxel_size, store_dir)
    raise InputError(f"unknown cloud store {kind!r}; choose memory or disk")
