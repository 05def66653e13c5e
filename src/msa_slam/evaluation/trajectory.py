"""Trajectory error metrics through evo (Grupp, 2017): ATE after SE(3) Umeyama alignment, RPE, % improvement.

ATE translation is the RMSE of position errors in metres; ATE rotation the RMSE of the rotation-angle
errors in degrees, both after aligning the estimate to the reference with a rigid (no scale) Umeyama fit.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from evo.core import filters, metrics
from evo.core.trajectory import PosePath3D
from evo.core.units import Unit

from msa_slam.errors import InputError
from msa_slam.types import validate_poses

RPE_UNITS = {"frames": Unit.frames, "meters": Unit.meters}


@dataclass(frozen=True)
class TrajectoryError:
    """RMSEs (metres, degrees) with the per-pose (ATE) or per-pair (RPE) errors they summarise."""

    translation_rmse: float
    rotation_rmse: float
    translation_errors: np.ndarray
    rotation_errors: np.ndarray


def _paths(estimate: np.ndarray, reference: np.ndarray, minimum: int) -> tuple[PosePath3D, PosePath3D]:
    est = validate_poses(estimate, "estimated trajectory")
    ref = validate_poses(reference, "reference trajectory")
    if len(est) != len(ref):
        raise InputError(f"estimated trajectory has {len(est)} poses but the reference has {len(ref)}")
    if len(est) < minimum:
        raise InputError(f"trajectory metrics need at least {minimum} poses, got {len(est)}")
    return PosePath3D(poses_se3=list(est)), PosePath3D(poses_se3=list(ref))


def _errors(ref: PosePath3D, est: PosePath3D, metric_type: type, **kwargs) -> tuple[np.ndarray, np.ndarray]:
    results = []
    for relation in (metrics.PoseRelation.translation_part, metrics.PoseRelation.rotation_angle_deg):
        metric = metric_type(relation, **kwargs)
        metric.process_data((ref, est))
        results.append(np.asarray(metric.error, dtype=np.float64))
    return results[0], results[1]


def _summary(trans: np.ndarray, rot: np.ndarray) -> TrajectoryError:
    return TrajectoryError(float(np.sqrt(np.mean(trans**2))), float(np.sqrt(np.mean(rot**2))), trans, rot)


def align_se3(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """`estimate` moved by the rigid transform that best fits its positions to `reference` (Umeyama)."""
    est, ref = _paths(estimate, reference, minimum=3)
    est.align(ref, correct_scale=False)
    return np.stack(est.poses_se3)


def ate(estimate: np.ndarray, reference: np.ndarray, align: bool = True) -> TrajectoryError:
    """Absolute trajectory error of matching (N, 4, 4) pose stacks; SE(3)-aligned first when `align`."""
    est, ref = _paths(estimate, reference, minimum=3 if align else 1)
    if align:
        est = copy.deepcopy(est)
        est.align(ref, correct_scale=False)
    return _summary(*_errors(ref, est, metrics.APE))


def rpe(estimate: np.ndarray, reference: np.ndarray, delta: float = 1, unit: str = "frames",
        tolerance: float = 0.1) -> TrajectoryError:
    """Relative pose error over pose pairs `delta` frames (or metres along the reference) apart."""
    if unit not in RPE_UNITS:
        raise InputError(f"unknown RPE unit {unit!r}; choose frames or meters")
    if not delta > 0:
        raise InputError(f"RPE delta must be > 0, got {delta}")
    est, ref = _paths(estimate, reference, minimum=2)
    try:
        trans, rot = _errors(ref, est, metrics.RPE, delta=delta, delta_unit=RPE_UNITS[unit],
                             rel_delta_tol=tolerance, all_pairs=False)
    except (metrics.MetricsException, filters.FilterException) as exc:
        raise InputError(f"RPE with delta {delta} {unit}: {exc}") from exc
    return _summary(trans, rot)


def improvement(before: float, after: float) -> float:
    """The paper's "% improvement": 100 * (before - after) / before (negative when `after` is worse)."""
    if not (np.isfinite(before) and np.isfinite(after)) or before <= 0:
        raise InputError(f"% improvement needs a positive finite 'before' error, got {before} -> {after}")
    return 100.0 * (before - after) / before
