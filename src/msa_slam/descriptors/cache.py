"""Descriptors of a whole sequence, computed once and cached on disk by the scans' identity, the descriptor's
settings and the code that computes them (this package and the scan readers: DESCRIPTOR_CODE)."""

from __future__ import annotations

from typing import Any

import numpy as np

from msa_slam.datasets import ScanSequence
from msa_slam.descriptors.base import Descriptor
from msa_slam.io.cache import CacheDir, cache_key, check_entry, named_files, sequence_inputs
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
                        quiet: bool = True) -> tuple[np.ndarray, bool]:
    """(N, *descriptor.shape) descriptors of every frame and whether they came from `cache` (entry
    `descriptors-<key>`, checked to have exactly that shape before it is used)."""
    name = f"descriptors-{key}"
    if cache is not None:
        cached = cache.load(name, lambda a: check_entry(a, (len(sequence), *descriptor.shape)))
        if cached is not None:
            return cached, True
    first = np.asarray(descriptor.compute(sequence[0].points, frame=0), dtype=np.float64)
    out = np.empty((len(sequence), *first.shape))
    out[0] = first
    with progress_bar(quiet) as bar:
        task = bar.add_task(f"descriptors ({descriptor.name})", total=len(sequence))
        bar.advance(task)
        for i in range(1, len(sequence)):
            out[i] = descriptor.compute(sequence[i].points, frame=i)
            bar.advance(task)
    if cache is not None:
        cache.save(name, out)
    return out, False
