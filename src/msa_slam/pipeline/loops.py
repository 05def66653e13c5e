"""Loop closures between keyframes: descriptor search, then small_gicp verification (paper, section V-A).

Every keyframe (in time order) queries the older keyframes by descriptor, leaving out the most recent
ones; its best match is recorded for the PR curve, and matches at or above the similarity threshold are
loop candidates. `oracle` mode (the paper) verifies only candidates within `loop_radius` of each other in
ground truth; `realistic` mode verifies every candidate. Verification registers the two downsampled
keyframe clouds and accepts the loop when the residual is below the gate; an accepted loop whose
ground-truth distance exceeds `loop_radius` is a false loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msa_slam.descriptors import Descriptor
from msa_slam.errors import InputError
from msa_slam.place_recognition import KeyframeDatabase
from msa_slam.registration import KeyframeCloudStore, Verifier


@dataclass(frozen=True)
class LoopCandidate:
    """A descriptor match between keyframes `query` (newer) and `match` (older), in frame indices."""

    query: int
    match: int
    similarity: float
    gt_distance: float
    verified: bool = False
    accepted: bool = False
    residual: float = float("nan")
    T_match_query: np.ndarray | None = None


@dataclass
class LoopSearch:
    """Best match of every keyframe query (for PR metrics) and the candidates above the threshold."""

    best_similarity: np.ndarray
    best_distance: np.ndarray
    candidates: list[LoopCandidate]


def _yaw_guess(descriptor: Descriptor, query_desc: np.ndarray, match_desc: np.ndarray) -> np.ndarray:
    """Initial T_match_query: the descriptor's yaw estimate (Scan Context's best column shift), else identity."""
    guess = np.eye(4)
    if hasattr(descriptor, "align"):
        _, yaw_deg = descriptor.align(query_desc, match_desc)
        c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
        guess[:2, :2] = [[c, -s], [s, c]]
    return guess


def search_loops(keyframes: np.ndarray, descriptors: np.ndarray, odometry: np.ndarray, gt: np.ndarray,
                 descriptor: Descriptor, threshold: float, min_frame_gap: int, exclude_recent: int,
                 top_k: int = 1) -> tuple[LoopSearch, KeyframeDatabase]:
    """Query each keyframe against the older ones (database of odometry poses and descriptors)."""
    database = KeyframeDatabase(descriptor)
    best_sim, best_dist, candidates = [], [], []
    for frame in keyframes:
        frame = int(frame)
        matches = database.query(frame, descriptors[frame], exclude_frames=min_frame_gap,
                                 exclude_recent=exclude_recent, threshold=0.0, top_k=max(1, top_k))
        for rank, match in enumerate(matches):
            dist = float(np.linalg.norm(gt[frame, :3, 3] - gt[match.keyframe_id, :3, 3]))
            if rank == 0:
                best_sim.append(match.similarity)
                best_dist.append(dist)
            if match.similarity >= threshold:
                candidates.append(LoopCandidate(frame, match.keyframe_id, match.similarity, dist))
        database.add(frame, odometry[frame], descriptors[frame])
    return LoopSearch(np.asarray(best_sim), np.asarray(best_dist), candidates), database


def verify_candidates(candidates: list[LoopCandidate], clouds: KeyframeCloudStore, verifier: Verifier,
                      descriptor: Descriptor, descriptors: np.ndarray, mode: str, loop_radius: float,
                      advance=lambda: None) -> list[LoopCandidate]:
    """Register candidate pairs (all in `realistic` mode, only GT-near ones in `oracle` mode)."""
    out = []
    for cand in candidates:
        if mode == "oracle" and cand.gt_distance > loop_radius:
            out.append(cand)
            advance()
            continue
        guess = _yaw_guess(descriptor, descriptors[cand.query], descriptors[cand.match])
        try:
            result = verifier.verify(clouds[cand.match], clouds[cand.query], initial_guess=guess)
        except InputError:  # clouds too sparse to register: the candidate is rejected, not the run
            out.append(LoopCandidate(cand.query, cand.match, cand.similarity, cand.gt_distance, True, False,
                                     float("inf")))
            advance()
            continue
        out.append(LoopCandidate(cand.query, cand.match, cand.similarity, cand.gt_distance, True,
                                 result.accepted, result.residual, result.T_target_source))
        advance()
    return out
