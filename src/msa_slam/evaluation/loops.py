"""Loop accounting: where loop closing lost the revisits ground truth says the robot made.

A run's loop records (slam/loop_closing.py) say what the descriptor search proposed and what verification
did with it; ground truth says which keyframe pairs were real revisits and what their relative pose was.
Put together they tell whether a method missed its loops at the search (no true candidate), at
verification (true candidates rejected, by reason) or not at all, which ATE alone cannot:

- `candidates`: keyframe pairs whose descriptor similarity reached the threshold; `true_candidates`: those
  whose keyframes lie within `loop_radius` of each other in ground truth.
- `registered`: candidates that went through registration (all in realistic mode; in oracle mode only the
  true ones); `accepted` + the sum of `rejected` (per slam.loop_closing.REJECTION_REASONS) == `registered`.
- `false_loops`: accepted loops whose measured relative pose (T_match_query) is off the ground-truth one
  by more than `loop_radius` metres of translation or FALSE_LOOP_ANGLE_DEG of rotation: the error
  inv(T_gt) @ T_match_query, with T_gt = inv(gt[match]) @ gt[query]. A false loop is a wrong constraint in the
  graph, whether its keyframes are near each other (registered to a wrong pose) or far apart.
- `distant_loops`: accepted loops whose keyframes are more than `loop_radius` apart in ground truth. Not wrong
  in themselves when the measured pose is right: the verified protocol registers keyframes up to
  MAX_LOOP_OFFSET_M apart (slam/loop_closing.py); the count says how far loop closing reaches.
- `revisits`: ground-truth revisits, the keyframe pairs within `loop_radius` of each other whose keyframes
  are at least `min_travel_m` apart along the ground-truth path (the loop closer's own condition for a
  candidate, measured on the odometry path); `revisits_closed`: those with an accepted loop;
  `revisit_recall` = closed / revisits. Every pair counts, so a method with dense keyframes has several
  pairs per place revisited while loop closing accepts at most `top_k` loops per keyframe: the recall of
  `revisit_keyframes` (keyframes with an older revisit partner) that got an accepted loop to one of them,
  `revisit_keyframe_recall`, compares methods of different keyframe densities.

Without ground truth only the counts that need none are given (candidates, registered, accepted, rejected);
the others are unavailable, for the reason under "loop_truth"; without any revisit both recalls are unavailable,
for the reason under "revisit_recall" (the keys of metrics.json `unavailable`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from msa_slam.evaluation.full_rate import path_length
from msa_slam.evaluation.metrics import LoopCounts, Unavailable, Value
from msa_slam.types import LoopClosure

FALSE_LOOP_ANGLE_DEG = 5.0  # rotation error beyond which an accepted loop's measured pose is false
NO_GROUND_TRUTH = "no ground truth: true candidates, false loops and revisits cannot be told"


def rejection_counts(loops: Sequence[LoopClosure], reasons: Sequence[str]) -> dict[str, int]:
    """Registered candidates rejected per reason (every reason listed, 0 when none)."""
    counts = dict.fromkeys(reasons, 0)
    for loop in loops:
        if loop.rejected:
            counts[loop.rejected] = counts.get(loop.rejected, 0) + 1
    return counts


def relative_pose_error(T_measured: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) of inv(T_true) @ T_measured."""
    error = np.linalg.inv(T_true) @ T_measured
    angle = np.degrees(np.arccos(np.clip((np.trace(error[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    return float(np.linalg.norm(error[:3, 3])), float(angle)


def is_false_loop(
    loop: LoopClosure, gt: np.ndarray, max_shift_m: float, max_angle_deg: float = FALSE_LOOP_ANGLE_DEG
) -> bool:
    """Whether an accepted loop's measured T_match_query is off the ground-truth relative pose of its keyframes
    (`gt`: every frame's pose) by more than `max_shift_m` or `max_angle_deg`."""
    if loop.T_match_query is None:
        raise ValueError(f"loop {loop.match} -> {loop.query} is accepted but has no measured relative pose")
    T_true = np.linalg.inv(gt[loop.match]) @ gt[loop.query]
    shift, angle = relative_pose_error(loop.T_match_query, T_true)
    return shift > max_shift_m or angle > max_angle_deg


def count_false_loops(loops: Sequence[LoopClosure], gt: np.ndarray, max_shift_m: float) -> int:
    """How many of `loops` are accepted and false (is_false_loop; `gt`: every frame's pose)."""
    return int(sum(is_false_loop(c, gt, max_shift_m) for c in loops if c.accepted))


def revisit_pairs(keyframes: np.ndarray, gt: np.ndarray, radius: float, min_travel_m: float) -> set[tuple[int, int]]:
    """Ground-truth revisits as (older, newer) keyframe frame pairs: within `radius` metres of each other and at
    least `min_travel_m` apart along the ground-truth path over every frame (`gt`: every frame's pose)."""
    keyframes = np.asarray(keyframes, dtype=np.int64)
    if len(keyframes) < 2:
        return set()
    path = path_length(gt)[keyframes]
    pairs = cKDTree(gt[keyframes, :3, 3]).query_pairs(radius, output_type="ndarray")
    pairs = np.sort(pairs, axis=1)  # rows of the keyframe list, older first (keyframes are in time order)
    far = path[pairs[:, 1]] - path[pairs[:, 0]] >= min_travel_m
    return {(int(keyframes[i]), int(keyframes[j])) for i, j in pairs[far]}


def account_loops(
    loops: Sequence[LoopClosure],
    keyframes: np.ndarray,
    gt: np.ndarray | None,
    radius: float,
    min_travel_m: float,
    reasons: Sequence[str],
) -> tuple[LoopCounts, dict[str, str]]:
    """The loop accounting of a run (module docstring: definitions), each count that cannot be given unavailable
    with why, and those reasons by key (loop_truth, revisit_recall): from its loop records, keyframe frame
    indices, every frame's ground-truth pose (None without), the true-loop radius (m), the candidates' minimum
    path apart (m) and the rejection reasons to list."""
    accepted = [c for c in loops if c.accepted]
    counts = (len(loops), int(sum(c.verified for c in loops)), len(accepted), rejection_counts(loops, reasons))
    if gt is None or not np.isfinite(gt).all():
        gone = Unavailable(NO_GROUND_TRUTH)
        return LoopCounts(*counts, *(gone,) * 9), {"loop_truth": NO_GROUND_TRUTH}
    revisits = revisit_pairs(keyframes, gt, radius, min_travel_m)
    closed = {(c.match, c.query) for c in accepted} & revisits
    partnered, partnered_closed = {newer for _, newer in revisits}, {newer for _, newer in closed}
    unavailable = {}
    if not revisits:
        unavailable["revisit_recall"] = (
            f"no keyframe pair within {radius:g} m in ground truth is {min_travel_m:g} m "
            "or more apart along the path (no revisit)"
        )

    def recall(found: int, total: int) -> Value:
        return found / total if total else Unavailable(unavailable["revisit_recall"])

    return LoopCounts(
        *counts,
        true_candidates=int(sum(c.gt_distance <= radius for c in loops)),
        false_loops=count_false_loops(accepted, gt, radius),
        distant_loops=int(sum(c.gt_distance > radius for c in accepted)),
        revisits=len(revisits),
        revisits_closed=len(closed),
        revisit_recall=recall(len(closed), len(revisits)),
        revisit_keyframes=len(partnered),
        revisit_keyframes_closed=len(partnered_closed),
        revisit_keyframe_recall=recall(len(partnered_closed), len(partnered)),
    ), unavailable
