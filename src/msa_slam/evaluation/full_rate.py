"""Full-rate trajectories and their errors: the same denominator for every sampler.

Keyframe-only ATE depends on which frames a sampler keeps (a sampler that keeps stalled frames is judged on
other poses than one that keeps one frame per metre), so the comparison metrics are computed on every
frame. After optimisation each frame takes its pose from the keyframe before it: the keyframe's optimised
pose times the odometry motion from that keyframe to the frame (frames before the first keyframe use the
first keyframe's correction). "Before" is the odometry itself, identical for every sampler of a comparison.

RPE is measured over fixed travelled distances, so it does not depend on the gaps between keyframes either:
the KITTI odometry benchmark's (segments of 100..800 m starting every STEP_FRAMES frames, the mean translation
error in % of the segment length and rotation in deg per 100 m, as its devkit computes them), and evo's
all-pairs RPE over 10 m of ground-truth path (the mean, in metres and degrees, that RPE_10M_EVO prints), so
that a reader can reproduce the number with evo. A run shorter than a
segment length gets None with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from evo.core import filters

from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import FullRateErrors, FullRateTrajectory
from msa_slam.evaluation.metrics_json import read_full_rate
from msa_slam.evaluation.metrics_reader import MetricsDocument
from msa_slam.evaluation.summary import ZERO_ERROR, Block, ate_or_reason, improvement_pct
from msa_slam.evaluation.trajectory import ATE_ALIGNMENT
from msa_slam.types import validate_poses

KITTI_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
SHORT_LENGTH_M = 10.0
SHORT_LENGTH_TOLERANCE = 0.1  # evo_rpe's default --delta_tol: pairs within 10 % of SHORT_LENGTH_M
# The evo command whose "mean" line is rpe_10m_translation_m (`--pose_relation angle_deg`: rpe_10m_rotation_deg)
RPE_10M_EVO = "evo_rpe tum {reference} {estimate} --delta 10 --delta_unit m --all_pairs --pairs_from_reference"
STEP_FRAMES = 10  # the KITTI devkit's step between segment starts


def full_rate_poses(odometry: np.ndarray, keyframes: np.ndarray, optimised: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses of every frame: the preceding keyframe's optimised pose composed with the odometry
    motion from that keyframe to the frame."""
    odometry = validate_poses(odometry, "odometry")
    keyframes = np.asarray(keyframes, dtype=np.int64)
    optimised = validate_poses(optimised, "optimised keyframe poses")
    if len(keyframes) != len(optimised) or not len(keyframes):
        raise InputError(f"full-rate trajectory: {len(keyframes)} keyframes but {len(optimised)} optimised poses")
    if np.any(np.diff(keyframes) <= 0) or keyframes[0] < 0 or keyframes[-1] >= len(odometry):
        raise InputError(f"full-rate trajectory: keyframes must be increasing frame indices in 0..{len(odometry) - 1}")
    correction = optimised @ np.linalg.inv(odometry[keyframes])  # world correction of each keyframe
    owner = np.clip(np.searchsorted(keyframes, np.arange(len(odometry)), side="right") - 1, 0, None)
    return correction[owner] @ odometry


def _rotation_deg(relative: np.ndarray) -> np.ndarray:
    cos = np.clip((np.trace(relative[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def path_length(poses: np.ndarray) -> np.ndarray:
    """Cumulative travelled distance (m) at each pose."""
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def _error_motions(estimate: np.ndarray, reference: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """(K, 4, 4) error inv(estimated motion) @ reference motion from each start to its end frame."""
    gt_motion = np.linalg.inv(reference[starts]) @ reference[ends]
    est_motion = np.linalg.inv(estimate[starts]) @ estimate[ends]
    return np.linalg.inv(est_motion) @ gt_motion


def _errors(error: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation (deg) of each error motion (empty arrays for none)."""
    if not len(error):
        return np.zeros(0), np.zeros(0)
    return np.linalg.norm(error[:, :3, 3], axis=1), _rotation_deg(error)


def segment_error_motions(estimate: np.ndarray, reference: np.ndarray, length: float, step: int = 1) -> np.ndarray:
    """(K, 4, 4) error inv(estimated motion) @ reference motion over every segment of `length` metres travelled
    along `reference`, starting every `step` frames and ending at the first frame at least `length` further
    (K = 0 when the path is shorter).

    The KITTI devkit (and kiss_icp.metrics.sequence_error, its port) ends a segment at the first frame *more*
    than `length` further; the two differ only where a frame lies exactly at that distance, and there this
    segment is the one of the nominal length its error is divided by (tests/test_full_rate.py compares them).
    """
    dist = path_length(reference)
    starts = np.arange(0, len(reference), step)
    ends = np.searchsorted(dist, dist[starts] + length, side="left")
    keep = ends < len(reference)
    return _error_motions(estimate, reference, starts[keep], ends[keep])


def segment_errors(
    estimate: np.ndarray, reference: np.ndarray, length: float, step: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation (deg) errors of the relative motion over every segment of `length`
    metres (segment_error_motions), as the KITTI devkit measures them; empty arrays when the path is shorter."""
    return _errors(segment_error_motions(estimate, reference, length, step))


def all_pairs_errors(
    estimate: np.ndarray, reference: np.ndarray, length: float, tolerance: float = SHORT_LENGTH_TOLERANCE
) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation (deg) errors over evo's all-pairs RPE pairs (`evo_rpe --delta length
    --delta_unit m --all_pairs --pairs_from_reference --delta_tol tolerance`): from every frame to the later one
    whose path distance along `reference` is nearest `length`, kept when within `tolerance` x `length` of it.
    evo's own filter chooses the pairs, so the numbers are evo's; the errors are computed here in one batch
    rather than pair by pair (evo's loop takes about 50 times longer)."""
    pairs = np.array(
        filters.filter_pairs_by_path(list(reference), length, length * tolerance, all_pairs=True), dtype=np.int64
    ).reshape(-1, 2)
    return _errors(_error_motions(estimate, reference, pairs[:, 0], pairs[:, 1]))


def distance_rpe(estimate: np.ndarray, reference: np.ndarray) -> tuple[Block, dict[str, str]]:
    """KITTI segment RPE (translation %, rotation deg/100 m; the devkit's mean over all segments) and evo's
    all-pairs 10 m RPE (m, deg; the mean over its pairs); None with the reason when the reference path has no
    segment or pair of that length."""
    out: Block = {}
    unavailable: dict[str, str] = {}
    total = float(path_length(reference)[-1])
    pairs = [segment_errors(estimate, reference, length, STEP_FRAMES) for length in KITTI_LENGTHS_M]
    t_rel = np.concatenate([t / length for (t, _), length in zip(pairs, KITTI_LENGTHS_M)])
    r_rel = np.concatenate([r / length for (_, r), length in zip(pairs, KITTI_LENGTHS_M)])
    if len(t_rel):
        out.update(
            rpe_kitti_translation_pct=float(100 * t_rel.mean()),
            rpe_kitti_rotation_deg_per_100m=float(100 * r_rel.mean()),
        )
    else:
        out.update(rpe_kitti_translation_pct=None, rpe_kitti_rotation_deg_per_100m=None)
        unavailable["rpe_kitti"] = (
            f"the ground-truth path is {total:.1f} m, shorter than KITTI's shortest segment ({KITTI_LENGTHS_M[0]:g} m)"
        )
    t10, r10 = all_pairs_errors(estimate, reference, SHORT_LENGTH_M)
    if len(t10):
        out.update(rpe_10m_translation_m=float(t10.mean()), rpe_10m_rotation_deg=float(r10.mean()))
    else:
        out.update(rpe_10m_translation_m=None, rpe_10m_rotation_deg=None)
        unavailable["rpe_10m"] = (
            f"no two frames of the {total:.1f} m ground-truth path are "
            f"{SHORT_LENGTH_M:g} +- {SHORT_LENGTH_M * SHORT_LENGTH_TOLERANCE:g} m apart along it"
        )
    return out, unavailable


def _block(estimate: np.ndarray, reference: np.ndarray) -> tuple[Block, str | None, dict[str, str]]:
    block, _, reason = ate_or_reason(estimate, reference)
    rpe, unavailable = distance_rpe(estimate, reference)
    return {**block, **rpe}, reason, unavailable


@dataclass(frozen=True)
class FullRateEvaluation:
    """Full-rate `trajectory` errors, and why those unavailable are (`reasons`: metrics.json `unavailable` keys)."""

    trajectory: FullRateTrajectory
    reasons: dict[str, str]


def evaluate_full_rate(odometry: np.ndarray, full_rate: np.ndarray, reference: np.ndarray | None) -> FullRateEvaluation:
    """Full-rate metrics: `before` (odometry) and `after` (full-rate optimised) ATE and distance RPE, the % ATE
    improvement and the alignment used, each undefined one unavailable with its reason."""
    if reference is None or not np.isfinite(reference).all():
        empty = dict.fromkeys(f.name for f in fields(FullRateErrors))
        return _evaluation(
            {
                "before": empty,
                "after": dict(empty),
                "improvement_pct": {"translation": None, "rotation": None},
                "frames": len(odometry),
                "ate_alignment": None,
            },
            {"full_rate_ate": "no ground-truth pose for every frame"},
        )
    before, reason_b, unavailable = _block(validate_poses(odometry, "odometry"), reference)
    after, reason_a, _ = _block(validate_poses(full_rate, "full-rate trajectory"), reference)
    if reason_b:
        unavailable["full_rate_ate"] = reason_b
    elif reason_a:
        unavailable["full_rate_ate_optimised"] = reason_a
    improvements = {}
    for part, key in (("translation", "ate_translation_m"), ("rotation", "ate_rotation_deg")):
        odometry_ate = before[key]
        improvements[part] = improvement_pct(odometry_ate, after[key])
        if improvements[part] is None and odometry_ate is not None and not odometry_ate > ZERO_ERROR:
            unavailable[f"full_rate_improvement_{part}"] = (
                f"odometry ATE {part} is 0 ({odometry_ate:.1g}): % improvement undefined"
            )
    return _evaluation(
        {
            "before": before,
            "after": after,
            "improvement_pct": improvements,
            "frames": len(reference),
            "ate_alignment": f"{ATE_ALIGNMENT}, fitted separately for each estimate on all {len(reference)} frames",
        },
        unavailable,
    )


def _evaluation(metrics: dict[str, object], reasons: dict[str, str]) -> FullRateEvaluation:
    """The evaluation with its figures typed, each undefined one unavailable with its reason."""
    return FullRateEvaluation(
        read_full_rate(MetricsDocument(metrics, "the full-rate evaluation", reasons=reasons)), reasons
    )
