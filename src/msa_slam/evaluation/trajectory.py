"""Trajectory error metrics through evo (Grupp, 2017): ATE after SE(3) Umeyama alignment, RPE, % improvement.

ATE translation is the RMSE of position errors in metres; ATE rotation the RMSE of the rotation-angle
errors in degrees, both after aligning the estimate to the reference with a rigid (no scale) Umeyama fit
(ATE_ALIGNMENT). That fit needs reference positions spread in at least two directions: a stationary or
rotation-only trajectory (or a perfectly straight one) leaves it undetermined (AlignmentError), and a short or
nearly straight one leaves the rotation about the direction of travel poorly determined, so the rotation ATE
mostly measures that fit (`alignment_warnings`).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from evo.core import filters, geometry, metrics
from evo.core.lie_algebra import LieAlgebraException
from evo.core.trajectory import PosePath3D
from evo.core.units import Unit
from scipy.spatial.transform import Rotation

from msa_slam.errors import InputError
from msa_slam.types import validate_poses

RPE_UNITS = {"frames": Unit.frames, "meters": Unit.meters}
ATE_ALIGNMENT = "SE(3) Umeyama (rotation + translation, no scale)"
# Standard deviation of the reference positions along their second principal axis, metres: below
# DEGENERATE_SPREAD_M the fit is undetermined; below STABLE_SPREAD_M its rotation about the travel direction
# rests on a few centimetres of lateral spread.
DEGENERATE_SPREAD_M = 1e-3
STABLE_SPREAD_M = 2.0
STABLE_POSES = 10
STABLE_PATH_M = 10.0


class AlignmentError(InputError):
    """The Umeyama fit is undetermined (reference positions on a point or a line)."""


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
    """(translation errors in metres, rotation-angle errors in degrees): evo's translation metric, and the rotation
    angles of the same error poses (an RPE's pairs, an APE's est^-1 ref) computed for the whole stack at once, as
    evo's rotation_angle_deg does one pose at a time (those calls were about a sixth of a comparison's time). The
    angles agree with evo's to rounding (1e-13 relative at most; the translations are evo's own)."""
    metric = metric_type(metrics.PoseRelation.translation_part, **kwargs)
    metric.process_data((ref, est))
    if metric_type is metrics.APE:  # its translation part compares positions only: the rotations' errors here
        rotations = np.einsum("nji,njk->nik", _rotations(est), _rotations(ref))
    else:
        rotations = np.asarray(metric.E, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :3]
    return np.asarray(metric.error, dtype=np.float64), _rotation_angles_deg(rotations)


def _rotations(path: PosePath3D) -> np.ndarray:
    return np.asarray(path.poses_se3, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :3]


def _rotation_angles_deg(rotations: np.ndarray) -> np.ndarray:
    """The rotation angle, degrees, of each (3, 3) matrix of an (N, 3, 3) stack: evo's so3_log_angle (the same
    check that each is a rotation, then the norm of scipy's rotation vector), for all of them in one call."""
    identity = np.broadcast_to(np.eye(3), rotations.shape)
    valid = (
        np.isclose(np.linalg.det(rotations), 1.0, atol=1e-6).all()
        and np.isclose(np.einsum("nji,njk->nik", rotations, rotations), identity, atol=1e-6).all()
    )
    if not valid:
        raise LieAlgebraException("matrix is not a valid SO(3) group element")
    if not len(rotations):
        return np.zeros(0)
    return np.abs(np.rad2deg(np.linalg.norm(Rotation.from_matrix(rotations).as_rotvec(), axis=1)))


def _summary(trans: np.ndarray, rot: np.ndarray) -> TrajectoryError:
    return TrajectoryError(float(np.sqrt(np.mean(trans**2))), float(np.sqrt(np.mean(rot**2))), trans, rot)


def second_spread(positions: np.ndarray) -> float:
    """Standard deviation (m) of (N, 3) positions along their second principal axis: 0 on a point or a line."""
    centred = positions - positions.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False)
    return float(singular[1] / np.sqrt(len(positions))) if len(singular) > 1 else 0.0


def alignment_warnings(reference: np.ndarray) -> list[str]:
    """Why an SE(3) fit to these reference poses would leave the rotation poorly determined (empty if stable)."""
    ref = validate_poses(reference, "reference trajectory")
    positions = ref[:, :3, 3]
    path = float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())
    spread = second_spread(positions)
    out = []
    if len(ref) < STABLE_POSES:
        out.append(f"only {len(ref)} poses (fewer than {STABLE_POSES})")
    if path < STABLE_PATH_M:
        out.append(f"ground-truth path {path:.1f} m (shorter than {STABLE_PATH_M:g} m)")
    if spread < STABLE_SPREAD_M:
        out.append(
            f"nearly straight: ground-truth positions spread {spread:.3f} m across the main direction "
            f"(less than {STABLE_SPREAD_M:g} m)"
        )
    return out


def _align(est: PosePath3D, ref: PosePath3D) -> PosePath3D:
    spread = second_spread(ref.positions_xyz)
    if spread < DEGENERATE_SPREAD_M:
        raise AlignmentError(
            f"SE(3) alignment undetermined: the {ref.num_poses} ground-truth positions lie on a "
            f"point or a line (spread {spread:.2g} m across it; stationary, rotation-only or "
            "straight trajectory)"
        )
    est = copy.deepcopy(est)
    try:
        est.align(ref, correct_scale=False)
    except geometry.GeometryException as exc:
        raise AlignmentError(f"SE(3) alignment undetermined: {exc}") from exc
    return est


def align_se3(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """`estimate` moved by the rigid transform that best fits its positions to `reference` (Umeyama);
    AlignmentError when the reference positions do not determine that transform."""
    est, ref = _paths(estimate, reference, minimum=3)
    return np.stack(_align(est, ref).poses_se3)


def ate(estimate: np.ndarray, reference: np.ndarray, align: bool = True) -> TrajectoryError:
    """Absolute trajectory error of matching (N, 4, 4) pose stacks; SE(3)-aligned first when `align`
    (AlignmentError when the reference positions do not determine the alignment)."""
    est, ref = _paths(estimate, reference, minimum=3 if align else 1)
    if align:
        est = _align(est, ref)
    return _summary(*_errors(ref, est, metrics.APE))


def rpe(
    estimate: np.ndarray, reference: np.ndarray, delta: float = 1, unit: str = "frames", tolerance: float = 0.1
) -> TrajectoryError:
    """Relative pose error over pose pairs `delta` frames (or metres along the reference) apart."""
    if unit not in RPE_UNITS:
        raise InputError(f"unknown RPE unit {unit!r}; choose frames or meters")
    if not delta > 0:
        raise InputError(f"RPE delta must be > 0, got {delta}")
    est, ref = _paths(estimate, reference, minimum=2)
    try:
        trans, rot = _errors(
            ref, est, metrics.RPE, delta=delta, delta_unit=RPE_UNITS[unit], rel_delta_tol=tolerance, all_pairs=False
        )
    except (metrics.MetricsException, filters.FilterException) as exc:
        raise InputError(f"RPE with delta {delta} {unit}: {exc}") from exc
    return _summary(trans, rot)


def improvement(before: float, after: float) -> float:
    """The paper's "% improvement": 100 * (before - after) / before (negative when `after` is worse)."""
    if not (np.isfinite(before) and np.isfinite(after)) or before <= 0:
        raise InputError(f"% improvement needs a positive finite 'before' error, got {before} -> {after}")
    return 100.0 * (before - after) / before
