"""Odometry of a whole sequence, computed once and cached on disk by its scans' identity, its configuration and
the code that computes it."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from msa_slam.datasets import Frame, ScanSequence
from msa_slam.io.cache import CacheDir, Computed, cache_key, check_entry, sequence_inputs
from msa_slam.io.fingerprint import code_fingerprint
from msa_slam.progress import progress_bar
from msa_slam.types import validate_poses

ODOMETRY_LIBRARIES = ("kiss-icp", "numpy", "scipy", "gtsam")  # scipy, gtsam: the deskew's SE(3) (odometry.deskew)
ODOMETRY_CODE = ("msa_slam.odometry", "msa_slam.datasets")  # the odometries and the scan readers: the cache key
PoseHook = Callable[[int, np.ndarray], None]  # called with each frame's index and pose as it is computed


class Odometry(Protocol):
    """What sequence_odometry needs; an odometry may also list `unregistered_frames` (KissOdometry: frames it
    could only extrapolate), which the cache keeps beside the poses."""

    @property
    def config(self) -> Mapping[str, Any]: ...

    def register(
        self, points: np.ndarray, timestamps: np.ndarray | None = None, time: float | None = None
    ) -> np.ndarray: ...


class OdometryCache:
    """`odometry-<key>.npy` pose stacks in a cache folder (see msa_slam.io.cache: verified, atomic, optional)."""

    def __init__(self, cache: CacheDir | str | os.PathLike) -> None:
        self.store = cache if isinstance(cache, CacheDir) else CacheDir(cache)

    @staticmethod
    def key(
        sequence: ScanSequence,
        config: Mapping[str, Any],
        extra_inputs: Iterable[str | os.PathLike] = (),
        store: CacheDir | None = None,
    ) -> str:
        """Key of the odometry of `sequence` (the identity of the scans it selects: another --first/--jump/-n
        is another entry) with `config` and `extra_inputs` (e.g. the pose file the odometry reads), computed
        by the code of ODOMETRY_CODE; `store` memoises the files' digests."""
        inputs = sequence_inputs(sequence, extra_inputs, store)
        return cache_key("odometry", inputs, dict(config), code_fingerprint(ODOMETRY_CODE), ODOMETRY_LIBRARIES)

    @staticmethod
    def source_key(identity: str, config: Mapping[str, Any]) -> str:
        """Key of the odometry with `config` of every frame of a source made in memory whose frames follow from
        `identity` (FrameSource.identity: a live: source's simulation key and laps), computed by ODOMETRY_CODE."""
        return cache_key(
            "odometry", {"frames": identity}, dict(config), code_fingerprint(ODOMETRY_CODE), ODOMETRY_LIBRARIES
        )

    def path(self, key: str) -> Path:
        return self.store.path(f"odometry-{key}")

    def load(self, key: str, expected_length: int | None = None) -> np.ndarray | None:
        """Cached poses, or None when absent or bad (truncated, NaN, not rigid, not float64 (N, 4, 4) with N
        `expected_length` when given: then recomputed)."""

        def check(poses: np.ndarray) -> np.ndarray:
            return validate_poses(check_entry(poses, (expected_length, 4, 4)), "odometry poses")

        return self.store.load(f"odometry-{key}", check)

    def load_unregistered(self, key: str, frames: int) -> list[int] | None:
        """The frames the cached odometry could not register (entry `unregistered-<key>`), or None when the entry
        is absent or bad (an entry written before these were kept: the odometry is then recomputed)."""

        def check(listed: np.ndarray) -> np.ndarray:
            listed = check_entry(listed, (None,))
            if not ((listed >= 0) & (listed < frames) & (listed == np.round(listed))).all():
                raise ValueError(f"expected frame indices below {frames}")
            return listed

        listed = self.store.load(f"unregistered-{key}", check)
        return None if listed is None else [int(f) for f in listed]

    def load_entry(self, key: str, frames: int) -> tuple[np.ndarray, list[int], np.ndarray] | None:
        """The cached poses of `frames` frames, the frames among them that were not registered and the time (ms)
        registering each took when computed, or None when any is absent or bad (the odometry is then
        recomputed)."""
        poses = self.load(key, expected_length=frames)
        if poses is None:
            return None
        unregistered = self.load_unregistered(key, frames)
        if unregistered is None:
            return None
        ms = self.store.load_times(f"odometry-{key}", frames)
        return None if ms is None else (poses, unregistered, ms)

    def save(self, key: str, poses: np.ndarray, unregistered: Iterable[int], ms: np.ndarray) -> Path | None:
        """Store the poses, the frames among them that were not registered and the time (ms) registering each
        took; None when the cache cannot be written (warned once). The list and times go first: poses without
        them are recomputed, never read alone."""
        self.store.save(f"unregistered-{key}", np.asarray(list(unregistered), dtype=np.float64))
        self.store.save_times(f"odometry-{key}", ms)
        return self.store.save(f"odometry-{key}", validate_poses(poses, "odometry poses"))


def sequence_odometry(
    sequence: ScanSequence,
    odometry: Odometry,
    cache: OdometryCache | None = None,
    quiet: bool = False,
    extra_inputs: Iterable[str | os.PathLike] = (),
    frames: Iterable[Frame] | None = None,
    label: str = "odometry",
    on_pose: PoseHook | None = None,
) -> Computed:
    """(N, 4, 4) odometry poses of every frame of `sequence`, whether they came from `cache` (which then
    also restores the odometry's `unregistered_frames`, so a cached run reports them as a fresh one does) and
    the time (ms) registering each frame took (as recorded in the cache when replayed).

    `extra_inputs`: files the odometry reads besides the scans (they are part of the cache key). The key is
    made from `odometry.config`, so the odometry comes configured for these scans (KISS-ICP's deskewing off
    when they have no per-point times: odometry.choice.make_odometry); scans without timestamps give the
    odometry no scan times (see KissOdometry.register). `frames`: the sequence's frames in order when a reader
    process or thread reads them ahead (pipeline.read_ahead; iterated only when the poses are computed), else they are read
    here one by one; `label`: the progress bar's; `on_pose(i, pose)` is called as each pose is computed (not for
    poses replayed from the cache).
    """
    key = None
    if cache is not None:
        key = OdometryCache.key(sequence, odometry.config, extra_inputs, cache.store)
        entry = cache.load_entry(key, len(sequence))
        if entry is not None:
            if hasattr(odometry, "unregistered_frames"):
                odometry.unregistered_frames = entry[1]
            return Computed(entry[0], True, entry[2])
    poses, ms = register_frames(
        odometry,
        iter(sequence) if frames is None else frames,
        len(sequence),
        sequence.times_known,
        quiet,
        label,
        on_pose,
    )
    if cache is not None and key is not None:
        cache.save(key, poses, getattr(odometry, "unregistered_frames", ()), ms)
    return Computed(poses, False, ms)


def register_frames(
    odometry: Odometry,
    frames: Iterable[Frame],
    n: int,
    times_known: bool,
    quiet: bool,
    label: str,
    on_pose: PoseHook | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(poses, ms registering each took) of the `n` `frames`, iterated to their end (a read-ahead knows it read
    every scan only there: pipeline.read_ahead); without timestamps (`times_known` False) the odometry is given
    no scan times (see KissOdometry.register); `on_pose(i, pose)` after each frame's registration."""
    poses, ms = np.empty((n, 4, 4)), np.empty(n)
    with progress_bar(quiet) as progress:
        task = progress.add_task(label, total=n)
        for i, frame in enumerate(frames):
            if i == n:
                raise RuntimeError(f"{label}: more frames than the {n} expected")
            start = time.perf_counter()  # per-point and scan times: used by KISS-ICP only with deskew on
            poses[i] = odometry.register(frame.points, frame.timestamps, frame.time if times_known else None)
            ms[i] = (time.perf_counter() - start) * 1e3
            if on_pose is not None:
                on_pose(i, poses[i])
            progress.advance(task)
    return poses, ms
