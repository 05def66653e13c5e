"""Descriptors of a whole sequence, computed once and cached on disk by the scans' identity, the descriptor's
settings and the code that computes them (this package and the scan readers: DESCRIPTOR_CODE)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from msa_slam.datasets import ScanSequence
from msa_slam.descriptors.base import Descriptor
from msa_slam.io.cache import CacheDir, Computed, cache_key, check_entry, named_files, sequence_inputs
from msa_slam.io.fingerprint import code_fingerprint
from msa_slam.progress import progress_bar

DESCRIPTOR_LIBRARIES = ("numpy", "numba", "torch")
DESCRIPTOR_CODE = ("msa_slam.descriptors", "msa_slam.datasets")  # all descriptors (imported by name) and readers


def descriptor_key(sequence: ScanSequence, name: str, params: dict[str, Any], cache: CacheDir | None = None) -> str:
    """Cache key of a sequence's descriptors: its scans' identity, files named in `params` (e.g. network
    weights) by content, the descriptor settings, DESCRIPTOR_CODE's fingerprint and library versions; `cache`
    memoises the files' digests."""
    inputs = sequence_inputs(sequence, named_files(params), cache)
    return cache_key(
        "descriptors",
        inputs,
        {"descriptor": name, "params": params},
        code_fingerprint(DESCRIPTOR_CODE),
        DESCRIPTOR_LIBRARIES,
    )


def load_descriptors(sequence: ScanSequence, descriptor: Descriptor, cache: CacheDir, key: str) -> Computed | None:
    """The cached descriptors of every frame (entry `descriptors-<key>`, checked to have exactly that shape before
    it is used) with the per-frame compute times recorded beside them, or None when either is absent or bad."""
    name = f"descriptors-{key}"
    cached = cache.load(name, lambda a: check_entry(a, (len(sequence), *descriptor.shape)))
    if cached is None:
        return None
    ms = cache.load_times(name, len(sequence))
    return None if ms is None else Computed(cached, True, ms)


def save_descriptors(cache: CacheDir | None, key: str, values: np.ndarray, ms: np.ndarray) -> Computed:
    """Store freshly computed descriptors and their per-frame compute times (ms; the times first: descriptors
    without them are recomputed, never read alone); `cache` None stores nothing."""
    if cache is not None:
        cache.save_times(f"descriptors-{key}", ms)
        cache.save(f"descriptors-{key}", values)
    return Computed(values, False, ms)


def compute_descriptors(
    sequence: ScanSequence, descriptor: Descriptor, cache: CacheDir | None, key: str, quiet: bool = True
) -> Computed:
    """(N, *descriptor.shape) descriptors of every frame, whether they came from `cache` (load_descriptors) and
    the time (ms) computing each took."""
    if cache is not None:
        cached = load_descriptors(sequence, descriptor, cache, key)
        if cached is not None:
            return cached
    return save_descriptors(cache, key, *describe_sequence(sequence, descriptor, quiet))


def describe_sequence(
    sequence: ScanSequence, descriptor: Descriptor, quiet: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """(descriptors, ms computing each took) of every frame, read and computed one after another."""
    values, ms = [], np.empty(len(sequence))
    with progress_bar(quiet) as bar:
        task = bar.add_task(f"descriptors ({descriptor.name})", total=len(sequence))
        for i in range(len(sequence)):
            values.append(describe(descriptor, sequence[i].points, i, ms))
            bar.advance(task)
    return np.stack(values), ms


def describe(descriptor: Descriptor, points: np.ndarray, frame: int, ms: np.ndarray) -> np.ndarray:
    """The float64 descriptor of frame `frame`'s `points`; the time computing it took goes to ms[frame]."""
    start = time.perf_counter()
    value = np.asarray(descriptor.compute(points, frame=frame), dtype=np.float64)
    ms[frame] = (time.perf_counter() - start) * 1e3
    return value
