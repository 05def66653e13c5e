"""Odometry of a whole sequence, computed once and cached on disk by sequence and configuration."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, Mapping, Protocol, Sequence

import numpy as np

from msa_slam.io.atomic import atomic_path
from msa_slam.progress import progress_bar
from msa_slam.types import validate_poses


class Odometry(Protocol):
    config: Mapping[str, Any]

    def register(self, points: np.ndarray, timestamps: np.ndarray | None = None) -> np.ndarray: ...


class OdometryCache:
    """A folder of `<key>.npy` pose stacks; the key hashes the sequence path and odometry configuration."""

    def __init__(self, cache_dir: str | os.PathLike) -> None:
        self.cache_dir = Path(cache_dir)

    @staticmethod
    def key(sequence: str | os.PathLike, config: Mapping[str, Any]) -> str:
        text = json.dumps({"sequence": os.path.abspath(os.fspath(sequence)), "config": config},
                          sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:24]

    def path(self, key: str) -> Path:
        return self.cache_dir / f"odometry-{key}.npy"

    def load(self, key: str, expected_length: int | None = None) -> np.ndarray | None:
        """Cached poses, or None when absent, unreadable or of the wrong length (then recomputed)."""
        path = self.path(key)
        if not path.is_file():
            return None
        try:
            poses = validate_poses(np.load(path, allow_pickle=False), str(path))
        except (OSError, ValueError):
            return None
        if expected_length is not None and len(poses) != expected_length:
            return None
        return poses

    def save(self, key: str, poses: np.ndarray) -> Path:
        poses = validate_poses(poses, "odometry poses")
        path = self.path(key)
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.save(handle, poses)
        return path


def sequence_odometry(frames: Sequence, odometry: Odometry, cache: OdometryCache | None = None,
                      sequence: str | os.PathLike | None = None, quiet: bool = False) -> np.ndarray:
    """(N, 4, 4) odometry poses of `frames` (objects with `.points`), from `cache` when it has them.

    `sequence` names the data for the cache key (required with a cache).
    """
    key = None
    if cache is not None:
        if sequence is None:
            raise ValueError("sequence_odometry: a cache needs the sequence path for its key")
        key = OdometryCache.key(sequence, odometry.config)
        cached = cache.load(key, expected_length=len(frames))
        if cached is not None:
            return cached
    poses = np.empty((len(frames), 4, 4))
    with progress_bar(quiet) as progress:
        task = progress.add_task("odometry", total=len(frames))
        for i in range(len(frames)):
            poses[i] = odometry.register(frames[i].points)
            progress.advance(task)
    if cache is not None and key is not None:
        cache.save(key, poses)
    return poses
