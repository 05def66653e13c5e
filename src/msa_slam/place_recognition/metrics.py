"""Precision/recall of recorded loop matches, as the MSA authors' place-recognition example scores them.

Each recorded match has a similarity and the ground-truth distance between query and match. For
thresholds 0.00..0.99: TP = sim >= thr and dist <= max_distance; FP = sim > thr and dist >
max_distance (the reference uses a strict '>' here; `strict_false_positive=False` uses '>=');
FN = sim < thr and dist <= max_distance. Precision is 1 when nothing is predicted, recall 0 when
nothing is positive, F1 0 when both are 0. PR-AUC = trapezoid area under precision over recall.

PR-AUC and F1-max are None (with the reason in `unavailable`) when they would only restate those
conventions: no recorded match, no match within `max_distance` (recall undefined: the score would read
0), no match beyond it (nothing to reject: it would read 1) or no match reaching any threshold.

Two protocols record the matches: the paper's batch search (each new keyframe's best match among the
older keyframes, msa_slam.slam.loop_closing) and the reference example's (`reference_protocol_matches`:
every frame against the keyframes nearest to it, docs/descriptors.md "Place-recognition protocols").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import trapezoid

from msa_slam.descriptors.base import Descriptor
from msa_slam.errors import InputError
from msa_slam.place_recognition.database import KeyframeDatabase

DEFAULT_THRESHOLDS = np.arange(100) / 100.0


@dataclass(frozen=True)
class PRCurve:
    """Precision, recall and F1 per threshold, with PR-AUC and F1-max (None, and why, when uninformative)."""

    thresholds: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    f1: np.ndarray
    auc: float | None
    f1_max: float | None
    f1_max_threshold: float | None
    unavailable: str | None = None

    def as_dict(self) -> dict:
        return {
            "pr_auc": self.auc,
            "f1_max": self.f1_max,
            "f1_max_threshold": self.f1_max_threshold,
            "unavailable": self.unavailable,
            "thresholds": self.thresholds.tolist(),
            "precision": self.precision.tolist(),
            "recall": self.recall.tolist(),
        }


def precision_recall(
    similarities: ArrayLike,
    distances: ArrayLike,
    max_distance: float = 3.0,
    thresholds: np.ndarray | None = None,
    strict_false_positive: bool = True,
) -> PRCurve:
    """PR curve, PR-AUC and F1-max of recorded matches (similarity, ground-truth distance in m)."""
    sim = np.asarray(similarities, dtype=np.float64).ravel()
    dist = np.asarray(distances, dtype=np.float64).ravel()
    if sim.shape != dist.shape:
        raise InputError(f"precision_recall: {sim.size} similarities but {dist.size} distances")
    if not (np.isfinite(sim).all() and np.isfinite(dist).all()):
        raise InputError("precision_recall: similarities and distances must be finite")
    thr = DEFAULT_THRESHOLDS if thresholds is None else np.asarray(thresholds, dtype=np.float64).ravel()
    if thr.size == 0:
        raise InputError("precision_recall: thresholds must not be empty")
    near = dist <= max_distance
    above = sim[None, :] >= thr[:, None]
    predicted_far = (sim[None, :] > thr[:, None]) if strict_false_positive else above
    tp = (above & near).sum(axis=1)
    fp = (predicted_far & ~near).sum(axis=1)
    fn = (~above & near).sum(axis=1)
    precision = np.where(tp + fp > 0, tp / np.maximum(tp + fp, 1), 1.0)
    recall = np.where(tp + fn > 0, tp / np.maximum(tp + fn, 1), 0.0)
    denom = precision + recall
    f1 = np.where(denom > 0, 2 * precision * recall / np.where(denom > 0, denom, 1.0), 0.0)
    reason = _unavailable(near, tp + fp, max_distance)
    if reason is not None:
        return PRCurve(thr, precision, recall, f1, None, None, None, reason)
    best = int(np.argmax(f1))
    auc = float(-trapezoid(precision, recall)) + 0.0  # + 0.0: no negative zero
    return PRCurve(thr, precision, recall, f1, auc, float(f1[best]), float(thr[best]))


def _unavailable(near: np.ndarray, predicted: np.ndarray, max_distance: float) -> str | None:
    """Why PR-AUC and F1-max carry no information about these matches (None when they do)."""
    if near.size == 0:
        return "no loop query had a match to score"
    queries = "1 query" if near.size == 1 else f"{near.size} queries"
    if not near.any():
        return (
            f"no best match of the {queries} lies within {max_distance:g} m in ground truth (no revisit): "
            "recall is undefined"
        )
    if near.all():
        return (
            f"the best match of each of the {queries} lies within {max_distance:g} m in ground truth (no wrong "
            "match to reject): precision is 1 by construction"
        )
    if not predicted.any():
        return "no match reached the lowest similarity threshold"
    return None


def reference_protocol_matches(
    descriptor: Descriptor,
    keyframes: np.ndarray,
    descriptors: np.ndarray,
    poses: np.ndarray,
    n_nearest: int = 10,
    min_gap: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """Similarities and distances (m) of the reference example's recorded matches: once more than
    `n_nearest` keyframes precede it, every frame compares its descriptor with the `n_nearest` keyframes
    before it that are nearest to its pose (`poses`: every frame's, ground truth for the distances), and
    the best match more than `min_gap` frames away is recorded. The MSA window's extra candidates of the
    reference are not offered (every sampler is scored on its keyframes alone)."""
    keyframes = np.asarray(keyframes, dtype=np.int64)
    database = KeyframeDatabase(descriptor)
    sims, dists = [], []
    added = 0
    for frame in range(len(poses)):
        while added < len(keyframes) and keyframes[added] < frame:
            database.add(int(keyframes[added]), poses[keyframes[added]], descriptors[keyframes[added]])
            added += 1
        if len(database) <= n_nearest:
            continue
        match = database.query_reference(frame, poses[frame], descriptors[frame], n_nearest, min_gap=min_gap)
        if match is not None:
            sims.append(match.similarity)
            dists.append(match.distance)
    return np.asarray(sims, dtype=np.float64), np.asarray(dists, dtype=np.float64)
