"""Loop closing for each new keyframe (paper, section V-A): descriptor search, then verification.

A new keyframe queries the older keyframes by descriptor, leaving out the most recent ones; its best match
is recorded for the PR curve, and matches at or above the similarity threshold are loop candidates.
`oracle` mode (the paper) verifies only candidates within `loop_radius` of each other in ground truth;
`realistic` mode verifies every candidate. Verification registers the two downsampled keyframe clouds and
accepts the loop when the residual is below the gate; an accepted loop whose ground-truth distance
exceeds `loop_radius` is a false loop.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from msa_slam.descriptors import Descriptor
from msa_slam.errors import InputError
from msa_slam.place_recognition import PRCurve, precision_recall
from msa_slam.registration import Verifier
from msa_slam.slam.keyframes import KeyframeStore
from msa_slam.types import LoopClosure


class LoopSettings(Protocol):
    """The loop-closing fields of the run configuration (msa_slam.pipeline.config.RunConfig)."""

    similarity_threshold: float
    min_frame_gap: int
    exclude_recent: int
    top_k: int
    mode: str
    loop_radius: float


def yaw_guess(descriptor: Descriptor, query_desc: np.ndarray, match_desc: np.ndarray) -> np.ndarray:
    """Initial T_match_query: the descriptor's yaw estimate (Scan Context's best column shift), else identity."""
    guess = np.eye(4)
    if hasattr(descriptor, "align"):
        _, yaw_deg = descriptor.align(query_desc, match_desc)
        c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
        guess[:2, :2] = [[c, -s], [s, c]]
    return guess


class LoopCloser:
    """Candidates of a new keyframe among the stored ones, and their verification; keeps every query's best
    match (similarity, ground-truth distance) for the PR curve."""

    def __init__(self, store: KeyframeStore, verifier: Verifier, settings: LoopSettings) -> None:
        self.store, self.verifier, self.settings = store, verifier, settings
        self.best_similarity: list[float] = []
        self.best_distance: list[float] = []

    def candidates(self, frame: int, descriptor: np.ndarray, gt: np.ndarray) -> list[LoopClosure]:
        """Older keyframes matching `frame` (call before adding it to the store); `gt` holds every frame's
        ground-truth pose, for the true-loop distance."""
        s = self.settings
        matches = self.store.database.query(frame, descriptor, exclude_frames=s.min_frame_gap,
                                            exclude_recent=s.exclude_recent, threshold=0.0, top_k=s.top_k)
        out = []
        for rank, match in enumerate(matches):
            dist = float(np.linalg.norm(gt[frame, :3, 3] - gt[match.keyframe_id, :3, 3]))
            if rank == 0:
                self.best_similarity.append(match.similarity)
                self.best_distance.append(dist)
            if match.similarity >= s.similarity_threshold:
                out.append(LoopClosure(frame, match.keyframe_id, match.similarity, dist))
        return out

    def verify(self, candidates: list[LoopClosure]) -> list[LoopClosure]:
        """Register candidate pairs (all in `realistic` mode, only GT-near ones in `oracle` mode)."""
        return [self._verify(c) for c in candidates]

    def _verify(self, cand: LoopClosure) -> LoopClosure:
        if self.settings.mode == "oracle" and cand.gt_distance > self.settings.loop_radius:
            return cand
        store = self.store
        guess = yaw_guess(store.descriptor, store.descriptor_of(cand.query), store.descriptor_of(cand.match))
        try:
            result = self.verifier.verify(store.cloud(cand.match), store.cloud(cand.query), initial_guess=guess)
        except InputError:  # clouds too sparse to register: the candidate is rejected, not the run
            return LoopClosure(cand.query, cand.match, cand.similarity, cand.gt_distance, True, False, float("inf"))
        return LoopClosure(cand.query, cand.match, cand.similarity, cand.gt_distance, True, result.accepted,
                           result.residual, result.T_target_source)

    def pr_curve(self) -> PRCurve | None:
        """Precision-recall of the best matches (None when no keyframe had an older one to query)."""
        if not self.best_similarity:
            return None
        return precision_recall(self.best_similarity, self.best_distance, self.settings.loop_radius)
