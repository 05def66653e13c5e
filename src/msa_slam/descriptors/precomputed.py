"""Descriptors computed elsewhere (any network, any per-frame shape), read from one .npy file.

The file holds an array (N, *shape): row i is frame i's descriptor. Similarity is 1/(1 + L2) of the
flattened arrays (the MSA paper's choice for learned descriptors), or Scan Context's best-shift
cosine for (rings, sectors) arrays.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from msa_slam.descriptors.base import validate_bank
from msa_slam.descriptors.scan_context import ScanContext
from msa_slam.errors import InputError

SIMILARITIES = ("inverse_l2", "scan_context")


def load_descriptor_file(path: str | Path, n_frames: int | None = None) -> np.ndarray:
    """(N, *shape) float64 descriptors from a .npy file; InputError on missing/corrupt file or wrong N."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"precomputed descriptors: file not found: {path}")
    with path.open("rb") as file:
        magic = file.read(6)
    if magic != b"\x93NUMPY":
        what = "a .npz archive" if magic.startswith(b"PK") else "not a .npy file (no NumPy header)"
        raise InputError(f"precomputed descriptors: {path} is {what}; expected one .npy array (np.save)")
    try:  # memory-mapped: a header that claims more than the file holds fails here, before any allocation
        data = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(
            f"precomputed descriptors: {path} is not a readable .npy array (truncated or corrupt: {exc})"
        ) from exc
    if data.dtype.kind not in "fiu":
        raise InputError(
            f"precomputed descriptors: {path} holds {data.dtype} values; expected real numbers (float or integer)"
        )
    if data.ndim < 2:
        raise InputError(
            f"precomputed descriptors: {path} must hold an array (N, ...) of N descriptors, got shape {data.shape}"
        )
    if n_frames is not None and len(data) != n_frames:
        raise InputError(f"precomputed descriptors: {path} has {len(data)} frames, the sequence has {n_frames}")
    finite = np.isfinite(data.reshape(len(data), -1)).all(axis=1)
    if not finite.all():
        raise InputError(f"precomputed descriptors: {path}: frame {int(np.argmin(finite))} has NaN or inf values")
    return np.array(data, dtype=np.float64)  # a copy in memory: the map closes with `data`


class PrecomputedDescriptors:
    """Looks descriptors up by frame index instead of computing them from points."""

    name = "precomputed"

    def __init__(self, path: str | Path, n_frames: int | None = None, similarity: str = "inverse_l2") -> None:
        if similarity not in SIMILARITIES:
            raise InputError(f"precomputed descriptors: similarity must be one of {SIMILARITIES}, got {similarity!r}")
        self.path = Path(path)
        self.descriptors = load_descriptor_file(self.path, n_frames)
        self.shape = self.descriptors.shape[1:]
        self._scan_context = None
        if similarity == "scan_context":
            if len(self.shape) != 2:
                raise InputError(f"precomputed descriptors: {path}: scan_context similarity needs (N, rings, sectors)")
            self._scan_context = ScanContext(n_ring=self.shape[0], n_sector=self.shape[1])

    def __len__(self) -> int:
        return len(self.descriptors)

    def compute(self, points: np.ndarray | None = None, frame: int | None = None) -> np.ndarray:
        """Descriptor of frame `frame` (the points are ignored)."""
        if frame is None or not 0 <= int(frame) < len(self.descriptors):
            raise InputError(f"precomputed descriptors: {self.path} has frames 0..{len(self) - 1}, asked for {frame}")
        return self.descriptors[int(frame)]

    def similarity_many(self, query: np.ndarray, bank: np.ndarray) -> np.ndarray:
        """Similarity of `query` with each row of `bank` (N, *shape)."""
        if self._scan_context is not None:
            return self._scan_context.similarity_many(query, bank)
        bank = validate_bank(bank, self.shape, f"precomputed descriptors ({self.path.name}) bank")
        q = validate_bank(np.asarray(query)[None], self.shape, "precomputed descriptors query")[0]
        return 1.0 / (1.0 + np.linalg.norm((bank - q).reshape(len(bank), -1), axis=1))

    def similarity(self, a: np.ndarray, b: np.ndarray) -> float:
        return float(self.similarity_many(a, np.asarray(b)[None])[0])
