"""The one interface every global descriptor offers, so samplers and the keyframe database need not care which.

A descriptor turns a LiDAR scan into an array (any fixed shape) and scores two such arrays with a
similarity where larger means "more likely the same place".
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from msa_slam.errors import InputError


@runtime_checkable
class Descriptor(Protocol):
    """Global place descriptor: extraction plus a similarity (higher = more similar)."""

    name: str

    @property
    def shape(self) -> tuple[int, ...]:
        """The shape of one descriptor."""
        ...

    def compute(self, points: np.ndarray | None, frame: int | None = None) -> np.ndarray:
        """Descriptor of one scan ((P, 3+) points in the sensor frame); `frame` is used by precomputed ones."""
        ...

    def similarity(self, a: np.ndarray, b: np.ndarray) -> float:
        """Similarity of two descriptors."""
        ...

    def similarity_many(self, query: np.ndarray, bank: np.ndarray) -> np.ndarray:
        """Similarities (N,) of one descriptor against a stack (N, *shape) of stored descriptors."""
        ...


@runtime_checkable
class SearchKeyed(Protocol):
    """A descriptor with a cheap search key for the two-stage search (Scan Context's ring key)."""

    def search_key(self, descriptor: np.ndarray) -> np.ndarray:
        """The key of one descriptor that the first stage's nearest-neighbour search compares."""
        ...


def scan_points(points: np.ndarray | None, where: str) -> np.ndarray:
    """The scan a descriptor computed from points needs (`compute` allows None only for precomputed ones)."""
    if points is None:
        raise InputError(f"{where}: no points given (this descriptor is computed from the scan)")
    return points


def validate_points(points: np.ndarray, where: str = "points") -> np.ndarray:
    """Return the (P, 3) xyz part of a point array as float64, or raise InputError naming `where`."""
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] < 3:
        raise InputError(f"{where}: expected points of shape (P, 3) or (P, 4), got {arr.shape}")
    xyz = np.ascontiguousarray(arr[:, :3], dtype=np.float64)
    if not np.isfinite(xyz).all():
        bad = int(np.argmin(np.isfinite(xyz).all(axis=1)))
        raise InputError(f"{where}: point {bad} has NaN or infinite coordinates")
    return xyz


def validate_bank(bank: np.ndarray, shape: tuple[int, ...], where: str = "descriptor bank") -> np.ndarray:
    """Return `bank` as float64 (N, *shape), or raise InputError naming the expected shape."""
    arr = np.asarray(bank, dtype=np.float64)
    if arr.ndim != len(shape) + 1 or arr.shape[1:] != tuple(shape):
        raise InputError(f"{where}: expected shape (N, {', '.join(map(str, shape))}), got {arr.shape}")
    return arr
