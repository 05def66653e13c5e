"""Scan Context (Kim & Kim, IROS 2018) configured as the MSA authors use it.

20 rings x 60 sectors up to 80 m; a cell holds the highest point (z + 2.0 m lidar height, at least 0)
of the 0.5 m voxel-centroid cloud. Similarity is the best cosine over the 60 column (yaw) shifts.
Semantics: docs/descriptors.md, "Scan Context".

Speed: binning is one numba pass; the shift search is a single matmul of the query's 60 rolled,
normalised copies against the flattened bank (no per-pair np.roll loop).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from msa_slam.descriptors.base import scan_points, validate_bank, validate_points
from msa_slam.descriptors.voxel import voxel_downsample
from msa_slam.errors import InputError

_RAD2DEG = 180.0 / np.pi  # numpy's np.degrees factor, so sectors match the reference bit for bit
_BANK_CHUNK = 4096  # rows per matmul block: bounds temporaries to ~40 MB


@numba.njit(cache=True)
def _floor_div(a: float, b: float) -> float:
    """numpy's floor_divide for floats (fmod based), which the reference uses via np.divmod."""
    mod = np.fmod(a, b)
    div = (a - mod) / b
    if mod != 0.0 and ((b < 0.0) != (mod < 0.0)):
        div -= 1.0
    if div != 0.0:
        fl = math.floor(div)
        if div - fl > 0.5:
            fl += 1.0
        return fl
    return 0.0


@numba.njit(cache=True, nogil=True)  # nogil: a reader thread (a bag's front end) bins beside the odometry
def _bin(xyz, n_ring, n_sector, max_radius, height_offset):
    out = np.zeros((n_ring, n_sector))
    gap_ring = max_radius / n_ring
    gap_sector = 360.0 / n_sector
    for i in range(xyz.shape[0]):
        x = xyz[i, 0]
        y = xyz[i, 1]
        if x == 0.0:
            x = 0.001
        if y == 0.0:
            y = 0.001
        h = xyz[i, 2] + height_offset
        ring = int(_floor_div(math.sqrt(x * x + y * y), gap_ring))
        if ring >= n_ring:
            ring = n_ring - 1
        theta = math.atan2(y, x) * _RAD2DEG
        if theta < 0.0:
            theta += 360.0
        sector = int(_floor_div(theta, gap_sector))
        if sector >= n_sector:
            sector = n_sector - 1
        if h > out[ring, sector]:
            out[ring, sector] = h
    return out


class ScanContext:
    """Scan Context descriptor (rings x sectors), with the authors' MSA configuration as defaults."""

    name = "scan_context"

    def __init__(
        self,
        n_ring: int = 20,
        n_sector: int = 60,
        max_radius: float = 80.0,
        lidar_height: float = 2.0,
        voxel_size: float | None = 0.5,
    ) -> None:
        if n_ring < 1 or n_sector < 1:
            raise InputError(f"scan_context: n_ring and n_sector must be >= 1, got {n_ring}, {n_sector}")
        if not max_radius > 0:
            raise InputError(f"scan_context: max_radius must be > 0, got {max_radius}")
        if voxel_size is not None and not voxel_size > 0:
            raise InputError(f"scan_context: voxel_size must be > 0 or None, got {voxel_size}")
        self.n_ring = int(n_ring)
        self.n_sector = int(n_sector)
        self.max_radius = float(max_radius)
        self.lidar_height = float(lidar_height)
        self.voxel_size = voxel_size
        self.shape = (self.n_ring, self.n_sector)

    def compute(self, points: np.ndarray | None, frame: int | None = None) -> np.ndarray:
        """Descriptor (n_ring, n_sector) of a raw scan: voxel downsampling, then binning."""
        try:
            scan = scan_points(points, "points")
            if self.voxel_size is not None:
                scan = voxel_downsample(scan, self.voxel_size)
            return self.bin(scan)
        except InputError as exc:
            raise InputError(f"scan_context: frame {frame}: {exc}" if frame is not None else str(exc)) from exc

    def bin(self, points: np.ndarray) -> np.ndarray:
        """Binning step alone, for clouds that are already downsampled."""
        xyz = validate_points(points)
        return _bin(xyz, self.n_ring, self.n_sector, self.max_radius, self.lidar_height)

    def _rolled_query(self, query: np.ndarray) -> np.ndarray | None:
        """(n_sector, n_ring*n_sector): every column shift of the unit-normalised query; None if zero."""
        q = validate_bank(np.asarray(query)[None], self.shape, "scan_context query")[0]
        norm = np.linalg.norm(q)
        if norm == 0.0:
            return None
        cols = (np.arange(self.n_sector)[None, :] - np.arange(self.n_sector)[:, None]) % self.n_sector
        return (q[:, cols].transpose(1, 0, 2) / norm).reshape(self.n_sector, -1)

    def shift_scores(self, query: np.ndarray, bank: np.ndarray) -> np.ndarray:
        """(N, n_sector) cosine of roll(query, k) with each stored descriptor; zero-norm pairs score 0."""
        bank = validate_bank(bank, self.shape)
        flat = bank.reshape(len(bank), -1)
        rolled = self._rolled_query(query)
        out = np.zeros((len(bank), self.n_sector))
        if rolled is None:
            return out
        for start in range(0, len(bank), _BANK_CHUNK):
            block = flat[start : start + _BANK_CHUNK]
            norms = np.sqrt(np.einsum("ij,ij->i", block, block))
            scores = block @ rolled.T
            nz = norms > 0
            out[start : start + len(block)][nz] = scores[nz] / norms[nz, None]
        return out

    def similarity_many(self, query: np.ndarray, bank: np.ndarray) -> np.ndarray:
        """Best-shift cosine similarity of `query` against each of `bank` (N, n_ring, n_sector)."""
        return self.shift_scores(query, bank).max(axis=1)

    def similarity(self, a: np.ndarray, b: np.ndarray) -> float:
        """max_k <roll(a, k), b> / (||a|| ||b||); 0 when either is all zeros."""
        return float(self.similarity_many(a, np.asarray(b)[None])[0])

    def align(self, a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
        """(similarity, yaw in degrees) such that rolling `a` by that many sectors best matches `b`."""
        scores = self.shift_scores(a, np.asarray(b)[None])[0]
        k = int(np.argmax(scores))
        return float(scores[k]), k * 360.0 / self.n_sector

    def ring_key(self, descriptor: np.ndarray) -> np.ndarray:
        """Rotation-invariant ring key (mean of each ring), the first-stage search key of the paper."""
        return np.asarray(descriptor, dtype=np.float64).mean(axis=-1)

    search_key = ring_key
