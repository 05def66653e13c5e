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
    return cache_key("descriptors", inputs, {"descriptor": name, "params": params}, code_fingerprint(DESCRIPTOR_CODE),
                     DESCRIPTOR_LIBRARIES)


def compute_descriptors(sequence: ScanSequence, descriptor: Descriptor, cache: CacheDir | None, key: str,
                        quiet: bool = True) -> Computed:
    """(N, *descriptor.shape) descriptors of every frame, whether they came from `cache` (entry
    `descriptors-<key>`, checked to have exactly that shape before it is used, with the per-frame compute times
    recorded beside it) and the time (ms) computing each took."""
    name = f"descriptors-{key}"
    if cache is not None:
        cached = cache.load(name, lambda a: check_entry(a, (len(sequence), *descriptor.shape)))
        ms = None if cached is None else cache.load_times(name, len(sequence))
        if ms is not None:
            return Computed(cached, True, ms)
    values, ms = [], np.empty(len(sequence))
    with progress_bar(quiet) as bar:
        task = bar.add_task(f"descriptors ({descriptor.name})", total=len(sequence))
        for i in range(len(sequence)):
            points = sequence[i].points
            start = time.perf_counter()
            values.append(np.asarray(descriptor.compute(points, frame=i), dtype=np.float64))
            ms[i] = (time.perf_counter() - start) * 1e3
            bar.advance(task)
    out = np.stack(values)
    if cache is not None:
        cache.save_times(name, ms)
        cache.save(name, out)
    return Computed(out, False, ms)
