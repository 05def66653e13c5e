"""Full-rate trajectories and distance-based RPE (msa_slam.evaluation.full_rate)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msa_slam.errors import InputError
from msa_slam.evaluation import evaluate_full_rate, full_rate_poses, segment_errors
from msa_slam.evaluation.metrics import Unavailable


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
    full = evaluate_full_rate(estimate, estimate, reference)
    assert full.trajectory.before.rpe_kitti_translation_pct == pytest.approx(2.0, rel=1e-9)
    assert full.trajectory.before.rpe_10m_translation_m == pytest.approx((990 * 0.2 + 0.18) / 991, rel=1e-9)
    assert "alignment undetermined" in full.reasons["full_rate_ate"]  # a line: the alignment is undetermined
    assert full.trajectory.before.ate_translation_m == Unavailable(full.reasons["full_rate_ate"])
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
    return rpe(
        ref,
        est,
        pose_relation[relation],
        delta=10,
        delta_unit=Unit.meters,
        rel_delta_tol=0.1,
        all_pairs=True,
        pairs_from_reference=True,
    ).stats["mean"]


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
    metrics = evaluate_full_rate(estimate, estimate, reference).trajectory.before
    assert "--all_pairs --pairs_from_reference" in RPE_10M_EVO and "--delta 10 --delta_unit m" in RPE_10M_EVO
    evo_mean = _evo_rpe_mean(reference, estimate, "trans_part")
    assert metrics.rpe_10m_translation_m == pytest.approx(evo_mean, rel=1e-9)
    assert metrics.rpe_10m_rotation_deg == pytest.approx(_evo_rpe_mean(reference, estimate, "angle_deg"), rel=1e-7)
    assert metrics.rpe_10m_translation_m > 0.1 and metrics.rpe_10m_rotation_deg > 1  # real errors, not zeros


def test_short_run_has_no_kitti_segments_and_says_why():
    reference = _circle(100, 10.0)  # 63 m of path
    full = evaluate_full_rate(_scaled(reference, 1.01), reference, reference)
    assert "62.2 m, shorter than KITTI's shortest segment (100 m)" in full.reasons["rpe_kitti"]
    assert full.trajectory.before.rpe_kitti_translation_pct == Unavailable(full.reasons["rpe_kitti"])
    assert full.trajectory.before.rpe_10m_translation_m > 0 and full.trajectory.after.ate_translation_m < 1e-9
    assert full.trajectory.improvement.translation == pytest.approx(100.0)


def test_without_ground_truth_full_rate_metrics_are_na():
    odometry = _circle(20, 5.0)
    nan = np.full_like(odometry, np.nan)
    full = evaluate_full_rate(odometry, odometry, nan)
    assert full.reasons == {"full_rate_ate": "no ground-truth pose for every frame"}
    gone = Unavailable("no ground-truth pose for every frame")
    assert full.trajectory.before.ate_translation_m == full.trajectory.improvement.translation == gone


def _drifting(reference: np.ndarray, seed: int) -> np.ndarray:
    """`reference` driven with noisy relative motions: drift that grows along the path."""
    rng = np.random.default_rng(seed)
    out = [reference[0]]
    for motion in np.linalg.inv(reference[:-1]) @ reference[1:]:
        noise = np.eye(4)
        noise[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.002, 3)).as_matrix()
        noise[:3, 3] = rng.normal(0, 0.05, 3)
        out.append(out[-1] @ motion @ noise)
    return np.stack(out)


@pytest.mark.parametrize("seed", [0, 1])
def test_kitti_segment_rpe_equals_kiss_icps_port_of_the_devkit(seed):
    """kiss_icp.metrics.sequence_error (its C++ port of the KITTI devkit) gives the same numbers on a path with
    no frame exactly at a segment's length: translation to its float32 result, and rotation once its degrees
    (per metre, with pi taken as 3.14) are put in deg per 100 m. It is not used here because it returns float32,
    uses 3.14 for pi and gives only these two means (no per-length segments, no 10 m RPE, no error vectors)."""
    from kiss_icp.metrics import sequence_error

    rng = np.random.default_rng(seed)
    reference = _circle(1500, 250.0)
    reference[:, :3, 3] += rng.normal(0, 0.05, (len(reference), 3))  # uneven steps: no exact segment lengths
    estimate = _drifting(reference, seed)
    ours = evaluate_full_rate(estimate, estimate, reference).trajectory.before
    translation_pct, rotation_deg_per_m = sequence_error(reference, estimate)
    assert ours.rpe_kitti_translation_pct == pytest.approx(translation_pct, rel=1e-6)
    assert ours.rpe_kitti_rotation_deg_per_100m / 100 * np.pi / 3.14 == pytest.approx(rotation_deg_per_m, rel=1e-6)
    assert ours.rpe_kitti_rotation_deg_per_100m / 100 != pytest.approx(rotation_deg_per_m, rel=1e-4)  # 3.14


def test_a_segment_ends_at_the_first_frame_at_least_its_length_away():
    """Where a frame lies exactly at the segment's length the devkit (and kiss-icp) take the next frame, one
    step longer than the length the error is divided by; here the segment is the nominal one."""
    from kiss_icp.metrics import sequence_error

    reference = np.tile(np.eye(4), (400, 1, 1))
    reference[:, 0, 3] = np.arange(400.0)  # 1 m steps: every segment end is exact
    estimate = _scaled(reference, 1.01)
    ours = evaluate_full_rate(estimate, estimate, reference).trajectory.before.rpe_kitti_translation_pct
    assert ours == pytest.approx(1.0, rel=1e-9)
    assert sequence_error(reference, estimate)[0] > 1.0 + 1e-3  # 101 m (201, 301 m) of 1 % error over 100 m
