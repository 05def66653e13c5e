"""Keyframe trajectory metrics (evaluation.metrics.KeyframeTrajectory): a number, or Unavailable with the reason.

Both pipelines report ATE/RPE of the keyframe trajectory before (odometry) and after optimisation and the
paper's % improvement. A trajectory whose SE(3) alignment is undetermined (stationary, rotation-only) gets
ATE unavailable with a reason instead of an exception; a short or nearly straight one keeps its numbers with a
warning that its rotation ATE mostly measures the alignment.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from msa_slam.evaluation.metrics import KeyframeTrajectory
from msa_slam.evaluation.metrics_json import read_keyframe_trajectory
from msa_slam.evaluation.metrics_reader import MetricsDocument
from msa_slam.evaluation.trajectory import ATE_ALIGNMENT, AlignmentError, alignment_warnings, ate, improvement, rpe

ESTIMATES = {"before": "odometry", "after": "optimised"}
ZERO_ERROR = 1e-9  # metres or degrees: an ATE this small is an exact fit


Block = dict[str, float | None]  # one estimate's errors by metrics.json key, None where undefined


@dataclass(frozen=True)
class TrajectoryEvaluation:
    """The keyframe trajectories' errors (`trajectory`), why those unavailable are (`reasons`: metrics.json
    `unavailable` keys), `warnings` about numbers that are present, and the per-keyframe ATE translation errors of
    each estimate (None where ATE is unavailable)."""

    trajectory: KeyframeTrajectory
    reasons: dict[str, str]
    warnings: list[str] = field(default_factory=list)
    errors: dict[str, np.ndarray | None] = field(default_factory=dict)


def improvement_pct(before: float | None, after: float | None) -> float | None:
    """The paper's % improvement, or None when either error is unavailable or `before` is 0 (up to rounding
    noise, ZERO_ERROR: the ratio of two rounding errors would be a random percentage)."""
    if before is None or after is None or not before > ZERO_ERROR:
        return None
    return improvement(before, after)


def ate_or_reason(estimate: np.ndarray, reference: np.ndarray) -> tuple[Block, np.ndarray | None, str | None]:
    """ATE translation/rotation RMSE and per-pose errors, or None values and the reason the alignment is
    undetermined (stationary, rotation-only, straight line)."""
    out: Block = {"ate_translation_m": None, "ate_rotation_deg": None}
    try:
        a = ate(estimate, reference)
    except AlignmentError as exc:
        return out, None, str(exc)
    out.update(ate_translation_m=a.translation_rmse, ate_rotation_deg=a.rotation_rmse)
    return out, a.translation_errors, None


def _errors(estimate: np.ndarray, reference: np.ndarray) -> tuple[Block, np.ndarray | None, str | None]:
    out, errors, reason = ate_or_reason(estimate, reference)
    r = rpe(estimate, reference, delta=1, unit="frames")
    out.update(rpe_translation_m=r.translation_rmse, rpe_rotation_deg=r.rotation_rmse)
    return out, errors, reason


def evaluate_trajectories(
    odometry: np.ndarray, optimised: np.ndarray, reference: np.ndarray | None, frames: np.ndarray
) -> TrajectoryEvaluation:
    """ATE/RPE of the odometry and optimised keyframe poses against ground truth at keyframe `frames`
    (`reference` None: a recording without ground truth, every metric None with that reason)."""
    if reference is None:
        block = dict.fromkeys(("ate_translation_m", "ate_rotation_deg", "rpe_translation_m", "rpe_rotation_deg"))
        metrics: dict[str, object] = {
            "before": block,
            "after": dict(block),
            "improvement_pct": {"translation": None, "rotation": None},
            "ate_alignment": None,
            "ate_rotation_reliable": None,
        }
        reasons = {"ate": "no ground truth", "rpe": "no ground truth"}
        return _evaluation(metrics, reasons, [], {"odometry": None, "optimised": None})
    blocks, errors, unavailable = {}, {}, {}
    for (key, name), estimate in zip(ESTIMATES.items(), (odometry, optimised)):
        blocks[key], errors[name], reason = _errors(estimate, reference)
        if reason is not None:
            unavailable[f"ate_{name}"] = reason
    if unavailable.get("ate_odometry") and unavailable.get("ate_odometry") == unavailable.get("ate_optimised"):
        unavailable = {"ate": unavailable["ate_odometry"]}
    improvements = {}
    for part, key in (("translation", "ate_translation_m"), ("rotation", "ate_rotation_deg")):
        before, after = blocks["before"][key], blocks["after"][key]
        improvements[part] = improvement_pct(before, after)
        if improvements[part] is None and before is not None and after is not None:
            unavailable[f"improvement_{part}"] = f"odometry ATE {part} is 0 ({before:.1g}): % improvement undefined"
    frames = np.asarray(frames)
    alignment = (
        f"{ATE_ALIGNMENT}, fitted separately for each estimate on the positions of all {len(frames)} "
        f"keyframes (frames {int(frames[0])}..{int(frames[-1])}) against ground truth"
    )
    unstable = alignment_warnings(reference) if "ate" not in unavailable else []
    warnings = (
        ["rotation ATE unreliable: the SE(3) alignment's rotation is poorly determined (" + "; ".join(unstable) + ")"]
        if unstable
        else []
    )
    metrics = {
        "before": blocks["before"],
        "after": blocks["after"],
        "improvement_pct": improvements,
        "ate_alignment": alignment,
        "ate_rotation_reliable": None if "ate" in unavailable else not unstable,
    }
    return _evaluation(metrics, unavailable, warnings, errors)


def _evaluation(
    metrics: Mapping[str, object], reasons: dict[str, str], warnings: list[str], errors: dict[str, np.ndarray | None]
) -> TrajectoryEvaluation:
    """The evaluation with its figures typed, each undefined one unavailable with its reason."""
    doc = MetricsDocument(metrics, "the keyframe evaluation", reasons=reasons)
    return TrajectoryEvaluation(read_keyframe_trajectory(doc), reasons, warnings, errors)
