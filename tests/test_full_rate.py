"""Full-rate trajectories and distance-based RPE (msa_slam.evaluation.full_rate)."""

from __future__ import annotations

import numpy as np
import pytest

from msa_slam.errors import InputError
from msa_slam.evaluation import evaluate_full_rate, full_rate_poses, segment_errors


def _circle(n: int, radius: float) -> np.ndarray:
    """Poses on a circle, heading along it."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    for pose, a in zip(poses, np.linspace(0, 2 * np.pi, n, endpoint=False)):
        yaw = a + np.pi / 2
        pose[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        pose[:2, 3] = radius * np.cos(a), radius * np.sin(a)
    return poses


def _scaled(poses: np.ndarray, scale: float) -> np.ndarray:
    """Every relative motion's translation scaled by `scale`."""
    out = [poses[0]]
    for motion in np.linalg.inv(poses[:-1]) @ poses[1:]:
        step = motion.copy()
        step[:3, 3] *= scale
        out.append(out[-1] @ step)
    return np.stack(out)


def test_every_frame_follows_its_preceding_keyframe():
    odometry = _scaled(_circle(50, 20.0), 1.05)
    keyframes = np.array([3, 10, 30])
    shift = np.eye(4)
    shift[:3, 3] = [1.0, -2.0, 0.5]
    optimised = shift @ odometry[keyframes]
    full = full_rate_poses(odometry, keyframes, optimised)
    np.testing.assert_allclose(full[keyframes], optimised, atol=1e-12)
    # frame 17 follows keyframe 10: its optimised pose times the odometry motion 10 -> 17
    np.testing.assert_allclose(full[17], optimised[1] @ np.linalg.inv(odometry[10]) @ odometry[17], atol=1e-12)
    # frames before the first keyframe take the first keyframe's correction
    np.testing.assert_allclose(full[:3], shift @ odometry[:3], atol=1e-12)
    np.testing.assert_allclose(full_rate_poses(odometry, keyframes, odometry[keyframes]), odometry, atol=1e-12)


def test_full_rate_refuses_mismatched_keyframes():
    odometry = _circle(10, 5.0)
    with pytest.raises(InputError, match="3 keyframes but 2 optimised"):
        full_rate_poses(odometry, np.array([0, 4, 8]), odometry[[0, 4]])
    with pytest.raises(InputError, match="increasing frame indices in 0..9"):
        full_rate_poses(odometry, np.array([0, 12]), odometry[[0, 1]])


def test_segment_rpe_measures_a_scale_error_per_travelled_distance():
    """On a straight road a 2 % scale error is 2 % of every segment however long: KITTI's percentage and
    0.2 m per 10 m (1 m steps put a frame exactly 10 m further; evo also pairs frame 990 with the last, 9 m
    further and within its 1 m tolerance: 0.18 m)."""
    reference = np.tile(np.eye(4), (1000, 1, 1))
    reference[:, 0, 3] = np.arange(1000.0)
    estimate = _scaled(reference, 1.02)
    metrics = evaluate_full_rate(estimate, estimate, reference)
    assert metrics["before"]["rpe_kitti_translation_pct"] == pytest.approx(2.0, rel=1e-9)
    assert metrics["before"]["rpe_10m_translation_m"] == pytest.approx((990 * 0.2 + 0.18) / 991, rel=1e-9)
    assert metrics["before"]["ate_translation_m"] is None  # a line: the alignment is undetermined
    assert "alignment undetermined" in metrics["unavailable"]["full_rate_ate"]
    trans, _ = segment_errors(estimate, reference, 800.0, step=10)
    assert len(trans) == 20 and np.allclose(trans, 16.0)


def _evo_rpe_mean(reference: np.ndarray, estimate: np.ndarray, relation: str) -> float:
    """The mean evo_rpe prints for `RPE_10M_EVO` (evo's own command function; relation: trans_part or angle_deg)."""
    from evo.core.metrics import PoseRelation, Unit
    from evo.core.trajectory import PoseTrajectory3D
    from evo.main_rpe import rpe

    stamps = np.arange(len(reference)) * 0.1
    ref, est = (PoseTrajectory3D(poses_se3=list(p), timestamps=stamps) for p in (reference, estimate))
    pose_relation = {"trans_part": PoseRelation.translation_part, "angle_deg": PoseRelation.rotation_angle_deg}
    return rpe(ref, est, pose_relation[relation], delta=10, delta_unit=Unit.meters, rel_delta_tol=0.1,
               all_pairs=True, pairs_from_reference=True).stats["mean"]


def test_10m_rpe_is_what_the_documented_evo_command_prints():
    """The 10 m RPE equals the mean of `evo_rpe ... --delta 10 --delta_unit m --all_pairs --pairs_from_reference`
    on a winding path with uneven steps (where the pair nearest 10 m is not the first frame past it) and a
    drifting, noisy estimate whose own path would choose other pairs."""
    from msa_slam.evaluation.full_rate import RPE_10M_EVO

    rng = np.random.default_rng(3)
    steps = rng.uniform(0.3, 1.7, 400)  # metres per frame
    yaw = np.cumsum(rng.normal(0, 0.05, 400))
    reference = np.tile(np.eye(4), (400, 1, 1))
    reference[:, 0, 3] = np.cumsum(steps * np.cos(yaw))
    reference[:, 1, 3] = np.cumsum(steps * np.sin(yaw))
    reference[:, 2, 3] = np.sin(np.arange(400) / 30.0)
    for pose, a in zip(reference, yaw):
        pose[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    estimate = _scaled(reference, 1.03)
    estimate[:, :3, 3] += rng.normal(0, 0.05, (400, 3))
    for pose, turn in zip(estimate, rng.normal(0, 0.02, 400)):  # heading noise (rad): a rotation error too
        pose[:3, :3] = pose[:3, :3] @ [[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]]
    metrics = evaluate_full_rate(estimate, estimate, reference)["before"]
    assert "--all_pairs --pairs_from_reference" in RPE_10M_EVO and "--delta 10 --delta_unit m" in RPE_10M_EVO
    assert metrics["rpe_10m_translation_m"] == pytest.approx(_evo_rpe_mean(reference, estimate, "trans_part"),
                                                            rel=1e-9)
    assert metrics["rpe_10m_rotation_deg"] == pytest.approx(_evo_rpe_mean(reference, estimate, "angle_deg"),
                                                           rel=1e-7)
    assert metrics["rpe_10m_translation_m"] > 0.1 and metrics["rpe_10m_rotation_deg"] > 1  # real errors, not zeros


def test_short_run_has_no_kitti_segments_and_says_why():
    reference = _circle(100, 10.0)  # 63 m of path
    metrics = evaluate_full_rate(_scaled(reference, 1.01), reference, reference)
    assert metrics["before"]["rpe_kitti_translation_pct"] is None
    assert "62.2 m, shorter than KITTI's shortest segment (100 m)" in metrics["unavailable"]["rpe_kitti"]
    assert metrics["before"]["rpe_10m_translation_m"] > 0 and metrics["after"]["ate_translation_m"] < 1e-9
    assert metrics["improvement_pct"]["translation"] == pytest.approx(100.0)


def test_without_ground_truth_full_rate_metrics_are_na():
    odometry = _circle(20, 5.0)
    nan = np.full_like(odometry, np.nan)
    metrics = evaluate_full_rate(odometry, odometry, nan)
    assert metrics["before"]["ate_translation_m"] is None and metrics["improvement_pct"]["translation"] is None
    assert metrics["unavailable"] == {"full_rate_ate": "no ground-truth pose for every frame"}
