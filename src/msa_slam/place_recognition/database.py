"""Keyframe database for loop candidates: poses and descriptors of kept keyframes, and two searches.

- `query`: the MSA paper's batch pipeline - the query descriptor against every older keyframe
  (exhaustive, or the Scan Context paper's two-stage search for large databases), threshold 0.8, top-k.
- `query_reference`: the authors' place-recognition example (docs/descriptors.md,
  "Place-recognition protocols") - best descriptor match among the 10 keyframes nearest by pose (+ extra candidates),
  recorded only when more than 10 frames apart.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from msa_slam.descriptors.base import Descriptor, SearchKeyed
from msa_slam.errors import InputError
from msa_slam.place_recognition.search import RingKeyIndex
from msa_slam.types import validate_pose

SEARCH_MODES = ("auto", "exhaustive", "two_stage")


@dataclass(frozen=True)
class LoopMatch:
    """A descriptor match found by the database: query frame, matched keyframe, similarity and the distance (m)
    between their stored poses. The SLAM core turns matches into msa_slam.types.LoopClosure (with the
    ground-truth distance and the verification outcome)."""

    query_id: int
    keyframe_id: int
    similarity: float
    distance: float


@dataclass(frozen=True)
class ExtraFrame:
    """A frame outside the database offered to `query_reference` (e.g. an MSA window member)."""

    frame_id: int
    pose: np.ndarray
    descriptor: np.ndarray


class KeyframeDatabase:
    """Growing store of keyframes (id, pose, descriptor) with descriptor search over past keyframes.

    `search="auto"` uses the two-stage search once the database holds `two_stage_min_size` keyframes
    and the descriptor offers a `search_key` (Scan Context's ring key); exhaustive otherwise.
    """

    def __init__(
        self,
        descriptor: Descriptor,
        search: str = "auto",
        two_stage_min_size: int = 10_000,
        n_candidates: int = 10,
        rebuild_every: int = 50,
    ) -> None:
        if search not in SEARCH_MODES:
            raise InputError(f"keyframe database: search must be one of {SEARCH_MODES}, got {search!r}")
        keyed = descriptor if isinstance(descriptor, SearchKeyed) else None
        if search == "two_stage" and keyed is None:
            raise InputError(f"keyframe database: descriptor {descriptor.name!r} has no search key for two_stage")
        self.descriptor = descriptor
        self.search = search
        self.two_stage_min_size = int(two_stage_min_size)
        self._keyed = keyed
        self._index = RingKeyIndex(n_candidates, rebuild_every) if keyed is not None else None
        self._n = 0
        self._ids = np.zeros(0, dtype=np.int64)
        self._poses = np.zeros((0, 4, 4))
        self._desc: np.ndarray | None = None
        self._keys: np.ndarray | None = None

    def __len__(self) -> int:
        return self._n

    @property
    def ids(self) -> np.ndarray:
        return self._ids[: self._n]

    @property
    def poses(self) -> np.ndarray:
        return self._poses[: self._n]

    @property
    def descriptors(self) -> np.ndarray:
        return self._desc[: self._n] if self._desc is not None else np.zeros((0,))

    @property
    def nbytes(self) -> int:
        """Bytes of the stored keyframes (ids, poses, descriptors, search keys), without spare capacity."""
        if self._n == 0:
            return 0
        per = self._ids.itemsize + self._poses[0].nbytes
        per += self.descriptors[0].nbytes + (self._keys[0].nbytes if self._keys is not None else 0)
        return per * self._n

    @property
    def bytes_per_keyframe(self) -> float:
        return self.nbytes / self._n if self._n else 0.0

    def add(self, frame_id: int, pose: np.ndarray, descriptor: np.ndarray) -> None:
        """Store a keyframe; the descriptor shape must match the first one stored."""
        pose = validate_pose(pose, f"keyframe {frame_id} pose")
        desc = np.asarray(descriptor, dtype=np.float64)
        if not np.isfinite(desc).all():
            raise InputError(f"keyframe {frame_id}: descriptor has NaN or infinite values")
        if self._desc is None:
            self._desc = np.zeros((0, *desc.shape))
            if self._keyed is not None:
                self._keys = np.zeros((0, *np.shape(self._keyed.search_key(desc))))
        if desc.shape != self._desc.shape[1:]:
            raise InputError(
                f"keyframe {frame_id}: descriptor shape {desc.shape}, database holds {self._desc.shape[1:]}"
            )
        if self._n == len(self._ids):
            self._grow(max(16, 2 * self._n))
        self._ids[self._n] = int(frame_id)
        self._poses[self._n] = pose
        self._desc[self._n] = desc
        if self._keys is not None and self._keyed is not None:
            self._keys[self._n] = self._keyed.search_key(desc)
        self._n += 1

    def _grow(self, capacity: int) -> None:
        def grown(arr: np.ndarray) -> np.ndarray:
            out = np.zeros((capacity, *arr.shape[1:]), dtype=arr.dtype)
            out[: self._n] = arr[: self._n]
            return out

        self._ids, self._poses = grown(self._ids), grown(self._poses)
        if self._desc is not None:
            self._desc = grown(self._desc)
        if self._keys is not None:
            self._keys = grown(self._keys)

    def eligible(self, frame_id: int, exclude_frames: int, exclude_recent: int) -> np.ndarray:
        """Mask of the stored keyframes more than `exclude_frames` frames before `frame_id` and not among the
        `exclude_recent` newest."""
        mask = (int(frame_id) - self.ids) > int(exclude_frames)
        if exclude_recent > 0:
            mask[max(0, self._n - int(exclude_recent)) :] = False
        return mask

    def _uses_two_stage(self, search: str | None) -> bool:
        mode = search or self.search
        if mode not in SEARCH_MODES:
            raise InputError(f"keyframe database: search must be one of {SEARCH_MODES}, got {mode!r}")
        if mode == "auto":
            return self._index is not None and self._n >= self.two_stage_min_size
        if mode == "two_stage" and self._index is None:
            raise InputError(f"keyframe database: descriptor {self.descriptor.name!r} has no search key")
        return mode == "two_stage"

    def query(
        self,
        frame_id: int,
        descriptor: np.ndarray,
        pose: np.ndarray | None = None,
        *,
        exclude_frames: int = 0,
        exclude_recent: int = 0,
        threshold: float = 0.8,
        top_k: int = 1,
        search: str | None = None,
        n_candidates: int | None = None,
    ) -> list[LoopMatch]:
        """Best matches (similarity >= threshold, best first, at most top_k) among keyframes with
        frame_id - id > exclude_frames, leaving out the `exclude_recent` newest keyframes.
        `search` and `n_candidates` (stage-1 neighbours of the two-stage search) override the defaults."""
        if self._n == 0:
            return []
        eligible = self.eligible(frame_id, exclude_frames, exclude_recent)
        if not eligible.any():
            return []
        rows: np.ndarray | slice
        two_stage = self._uses_two_stage(search)  # then the descriptor is keyed and its keys stored
        if two_stage and self._keyed is not None and self._index is not None and self._keys is not None:
            key = self._keyed.search_key(descriptor)
            rows = self._index.candidates(self._keys[: self._n], key, eligible, n_candidates)
            if len(rows) == 0:
                return []
        else:
            rows = np.flatnonzero(eligible)
            if len(rows) == self._n:
                rows = slice(None)  # avoid copying the whole bank
        sims = np.asarray(self.descriptor.similarity_many(descriptor, self.descriptors[rows]))
        idx = np.arange(self._n)[rows]
        keep = sims >= threshold
        sims, idx = sims[keep], idx[keep]
        order = np.argsort(-sims, kind="stable")[: int(top_k)]
        t = None if pose is None else validate_pose(pose, f"frame {frame_id} pose")[:3, 3]
        return [self._match(frame_id, t, int(idx[o]), float(sims[o])) for o in order]

    def _match(self, frame_id: int, t: np.ndarray | None, row: int, sim: float) -> LoopMatch:
        dist = float("nan") if t is None else float(np.linalg.norm(self._poses[row, :3, 3] - t))
        return LoopMatch(int(frame_id), int(self._ids[row]), sim, dist)

    def nearest_by_pose(self, pose: np.ndarray, k: int) -> np.ndarray:
        """Rows of the k keyframes nearest to `pose` by translation (ties: older first)."""
        t = validate_pose(pose)[:3, 3]
        d = np.linalg.norm(self.poses[:, :3, 3] - t, axis=1)
        return np.argsort(d, kind="stable")[: int(k)]

    def query_reference(
        self,
        frame_id: int,
        pose: np.ndarray,
        descriptor: np.ndarray,
        n_nearest: int = 10,
        extra: Iterable[ExtraFrame] = (),
        min_gap: int = 10,
    ) -> LoopMatch | None:
        """The reference example's protocol: best match among the `n_nearest` keyframes by pose plus
        `extra` candidates; returned only when |frame_id - match| > min_gap. Call it for frames after
        the sampler holds more than `n_nearest` keyframes, as the reference does."""
        pose = validate_pose(pose, f"frame {frame_id} pose")
        rows = self.nearest_by_pose(pose, n_nearest) if self._n else np.zeros(0, dtype=np.int64)
        extra = list(extra)
        ids = [int(i) for i in self._ids[rows]] + [int(c.frame_id) for c in extra]
        if not ids:
            return None
        cand_t = [self._poses[r, :3, 3] for r in rows] + [validate_pose(c.pose)[:3, 3] for c in extra]
        bank = np.stack(
            [self.descriptors[r] for r in rows] + [np.asarray(c.descriptor, dtype=np.float64) for c in extra]
        )
        sims = np.asarray(self.descriptor.similarity_many(descriptor, bank))
        best = int(np.argmax(sims))
        if abs(int(frame_id) - ids[best]) <= min_gap:
            return None
        dist = float(np.linalg.norm(cand_t[best] - pose[:3, 3]))
        return LoopMatch(int(frame_id), ids[best], float(sims[best]), dist)
