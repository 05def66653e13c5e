"""Trajectory metrics on constructed cases with known values; memory and time accounting."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msa_slam.errors import InputError
from msa_slam.evaluation import StageTimer, align_se3, array_bytes, ate, improvement, peak_rss_bytes, rpe


def _curve(n: int = 40) -> np.ndarray:
    """A non-degenerate 3-D path: a helix with heading along the tangent."""
    t = np.linspace(0, 3 * np.pi, n)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, 3] = np.stack([10 * np.cos(t), 10 * np.sin(t), 0.5 * t], axis=1)
    poses[:, :3, :3] = Rotation.from_euler("z", (t + np.pi / 2)[:, None]).as_matrix()
    return poses


def _rigid(yaw_deg: float, shift: list[float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zyx", [yaw_deg, 5, -3], degrees=True).as_matrix()
    T[:3, 3] = shift
    return T


def test_rigidly_moved_trajectory_has_zero_ate_after_alignment():
    ref = _curve()
    moved = _rigid(40, [5, -3, 2]) @ ref
    aligned = ate(moved, ref)
    assert aligned.translation_rmse < 1e-9 and aligned.rotation_rmse < 1e-6
    np.testing.assert_allclose(align_se3(moved, ref), ref, atol=1e-9)
    unaligned = ate(moved, ref, align=False)
    assert unaligned.translation_rmse > 1.0 and unaligned.rotation_rmse > 10


def test_constant_offset_gives_known_unaligned_rmse_and_zero_aligned():
    ref = _curve()
    est = ref.copy()
    est[:, :3, 3] += [0.3, 0.4, 0.0]  # 0.5 m everywhere
    assert ate(est, ref, align=False).translation_rmse == pytest.approx(0.5)
    assert ate(est, ref).translation_rmse == pytest.approx(0.0, abs=1e-9)


def test_alternating_noise_gives_known_rmse():
    ref = _curve(41)
    est = ref.copy()
    signs = np.where(np.arange(41) % 2 == 0, 1.0, -1.0)
    est[:, :3, 3] += signs[:, None] * np.array([0.0, 0.0, 0.2])
    # Nearly zero-mean +-0.2 m vertical noise: alignment cannot remove it, RMSE stays ~0.2 m.
    assert ate(est, ref).translation_rmse == pytest.approx(0.2, abs=0.005)
    assert ate(est, ref, align=False).translation_rmse == pytest.approx(0.2)


def test_rotation_error_in_degrees():
    ref = _curve()
    est = ref.copy()
    est[:, :3, :3] = est[:, :3, :3] @ Rotation.from_euler("x", 2.0, degrees=True).as_matrix()
    result = ate(est, ref, align=False)
    np.testing.assert_allclose(result.rotation_errors, 2.0, atol=1e-6)
    assert result.translation_rmse == pytest.approx(0.0, abs=1e-12)


def test_rpe_of_known_per_step_error():
    n = 30
    ref = np.tile(np.eye(4), (n, 1, 1))
    ref[:, 0, 3] = np.arange(n) * 1.0
    est = ref.copy()
    est[:, 0, 3] = np.arange(n) * 1.1  # every step 10 cm too long
    per_frame = rpe(est, ref, delta=1)
    np.testing.assert_allclose(per_frame.translation_errors, 0.1, atol=1e-12)
    assert per_frame.translation_rmse == pytest.approx(0.1)
    per_5m = rpe(est, ref, delta=5, unit="meters")
    assert per_5m.translation_rmse == pytest.approx(0.5)
    assert per_5m.rotation_rmse == pytest.approx(0.0, abs=1e-9)


def test_improvement_matches_paper_definition():
    assert improvement(2.0, 0.5) == pytest.approx(75.0)
    assert improvement(1.0, 1.5) == pytest.approx(-50.0)
    with pytest.raises(InputError, match="positive"):
        improvement(0.0, 1.0)


def test_bad_trajectories_raise():
    ref = _curve(10)
    with pytest.raises(InputError, match="9 poses but the reference has 10"):
        ate(ref[:9], ref)
    bad = ref.copy()
    bad[4, 0, 3] = np.nan
    with pytest.raises(InputError, match="frame 4"):
        ate(bad, ref)
    with pytest.raises(InputError, match="unit"):
        rpe(ref, ref, unit="parsecs")
    with pytest.raises(InputError, match="RPE with delta 1000"):
        rpe(ref, ref, delta=1000, unit="meters")
    with pytest.raises(InputError, match="at least 3"):
        ate(ref[:2], ref[:2])


def test_memory_and_stage_timer():
    a = np.zeros((100, 3), dtype=np.float32)
    b = np.zeros(10, dtype=np.float64)
    assert array_bytes(a, b, None) == 1200 + 80
    before = peak_rss_bytes()
    big = np.ones(30_000_000 // 8)  # ~30 MB touched
    assert big.sum() > 0 and peak_rss_bytes() >= before > 1_000_000
    timer = StageTimer()
    with timer.stage("a"):
        time.sleep(0.02)
    with timer.stage("a"):
        time.sleep(0.02)
    with pytest.raises(RuntimeError):
        with timer.stage("b"):
            raise RuntimeError("boom")
    assert 0.04 <= timer.seconds["a"] < 0.5 and "b" in timer.seconds
    assert timer.total == pytest.approx(sum(timer.seconds.values()))
