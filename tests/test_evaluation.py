"""Trajectory metrics on constructed cases with known values; memory and time accounting."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.metrics import seed_row
from scipy.spatial.transform import Rotation

import msa_slam.evaluation.resources as resources
from msa_slam.errors import InputError
from msa_slam.evaluation import (
    AlignmentError,
    StageTimer,
    align_se3,
    alignment_warnings,
    array_bytes,
    ate,
    evaluate_trajectories,
    fmt,
    improvement,
    improvement_pct,
    notes,
    peak_rss_bytes,
    rpe,
)
from msa_slam.evaluation.metrics import Unavailable


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


def test_memory_accounting():
    a = np.zeros((100, 3), dtype=np.float32)
    b = np.zeros(10, dtype=np.float64)
    assert array_bytes(a, b, None) == 1200 + 80
    before = peak_rss_bytes()
    big = np.ones(30_000_000 // 8)  # ~30 MB touched
    assert big.sum() > 0 and peak_rss_bytes() >= before > 1_000_000


def test_stage_timer_accumulates_and_records_failing_stages(monkeypatch):
    clock = iter([10.0, 10.5, 20.0, 20.25, 30.0, 31.0])
    monkeypatch.setattr(resources.time, "perf_counter", lambda: next(clock))
    timer = StageTimer()
    with timer.stage("a"):
        pass
    with timer.stage("a"):
        pass
    with pytest.raises(RuntimeError):
        with timer.stage("b"):
            raise RuntimeError("boom")
    assert timer.seconds == {"a": 0.75, "b": 1.0} and timer.total == 1.75


def _spin(n: int = 30, step: np.ndarray | None = None) -> np.ndarray:
    """Poses turning about z on the spot (or moving by `step` per pose)."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("z", np.linspace(0, 2 * np.pi, n)[:, None]).as_matrix()
    if step is not None:
        poses[:, :3, 3] = np.arange(n)[:, None] * step
    return poses


@pytest.mark.parametrize(
    "reference",
    [_spin(), np.tile(np.eye(4), (30, 1, 1)), _spin(step=np.array([1.0, 0, 0]))],
    ids=["rotation-only", "stationary", "straight"],
)
def test_undetermined_alignment_gives_ate_none_with_reason(reference):
    estimate = reference.copy()
    estimate[:, :3, :3] = estimate[:, :3, :3] @ Rotation.from_euler("z", 1.0, degrees=True).as_matrix()
    with pytest.raises(AlignmentError, match="alignment undetermined.*point or a line"):
        ate(estimate, reference)
    with pytest.raises(AlignmentError):
        align_se3(estimate, reference)
    assert ate(estimate, reference, align=False).rotation_rmse == pytest.approx(1.0)  # unaligned ATE still works
    ev = evaluate_trajectories(estimate, reference, reference, np.arange(len(reference)))
    m, why = ev.trajectory, ev.reasons
    assert list(why) == ["ate"] and "undetermined" in why["ate"]
    gone = Unavailable(why["ate"])
    assert m.before.ate_translation_m == m.before.ate_rotation_deg == gone
    assert m.after.ate_translation_m == m.after.ate_rotation_deg == gone
    assert m.improvement.translation == m.improvement.rotation == gone
    assert ev.errors == {"odometry": None, "optimised": None} and m.rotation_reliable == gone
    # RPE needs no alignment: a constant 1 degree offset leaves the relative motions exact
    assert m.before.rpe_rotation_deg == pytest.approx(0.0, abs=1e-6)
    assert notes(why, ev.warnings)[0].startswith("ATE (and its % improvement) n/a: SE(3) alignment undetermined")


def test_short_straight_run_warns_that_rotation_ate_is_unreliable():
    n = 30
    ref = np.tile(np.eye(4), (n, 1, 1))
    ref[:, 0, 3] = np.arange(n) * 1.0
    ref[:, 1, 3] = 0.05 * np.sin(np.arange(n))  # 5 cm of lateral wobble over 29 m
    est = ref.copy()
    est[:, 2, 3] += 0.01 * (-1.0) ** np.arange(n)  # 1 cm of vertical noise
    assert alignment_warnings(ref) == [
        f"nearly straight: ground-truth positions spread {0.05 * np.std(np.sin(np.arange(n))):.3f} m across the "
        "main direction (less than 2 m)"
    ]
    ev = evaluate_trajectories(est, ref, ref, np.arange(n))
    assert ev.trajectory.before.ate_translation_m == pytest.approx(0.01, rel=0.05)
    assert ev.trajectory.rotation_reliable is False
    assert (
        len(ev.warnings) == 1
        and ev.warnings[0].startswith("rotation ATE unreliable")
        and "nearly straight" in ev.warnings[0]
    )
    assert "all 30 keyframes (frames 0..29)" in ev.trajectory.alignment
    small = _curve(8)
    small[:, :3, 3] *= 0.05  # a 5 m stretch of the helix
    short = alignment_warnings(small)
    assert any("only 8 poses" in w for w in short) and any("path" in w and "shorter than 10 m" in w for w in short)


def test_well_spread_run_has_no_alignment_warning():
    ref = _curve(41)
    odometry = ref.copy()
    odometry[:, 2, 3] += 0.2 * (-1.0) ** np.arange(41)
    ev = evaluate_trajectories(_rigid(10, [1, 2, 3]) @ odometry, ref, ref, np.arange(41))
    m = ev.trajectory
    assert alignment_warnings(ref) == [] and ev.warnings == [] and ev.reasons == {}
    assert m.rotation_reliable is True and m.before.ate_translation_m == pytest.approx(0.2, abs=0.005)
    assert m.improvement.translation == pytest.approx(100.0)
    perfect = evaluate_trajectories(ref, ref, ref, np.arange(41))
    why = perfect.reasons["improvement_translation"]
    assert "odometry ATE translation is 0" in why and perfect.trajectory.improvement.translation == Unavailable(why)
    assert isinstance(perfect.trajectory.improvement.rotation, Unavailable)


def test_improvement_pct_is_none_when_undefined():
    assert improvement_pct(2.0, 0.5) == pytest.approx(75.0)
    assert improvement_pct(None, 0.5) is None and improvement_pct(0.5, None) is None
    assert improvement_pct(0.0, 0.0) is None


def test_fmt_prints_na_and_never_negative_zero():
    assert fmt(-0.04, ".1f", " %") == "0.0 %" and fmt(-0.0) == "0.000" and fmt(-0.0004, ".3f") == "0.000"
    assert fmt(-1.25, ".1f") == "-1.2" and fmt(-0.0004, ".1e") == "-4.0e-04"
    assert fmt(None) == fmt(float("nan")) == "n/a" and fmt(3, "d") == "3"


def test_spec_for_gives_each_kind_of_metric_one_number_of_decimals():
    from msa_slam.evaluation.display import spec_for

    assert {
        spec_for(k) for k in ("ate_after_m", "rpe_pct", "rpe_kitti_rotation_deg_per_100m", "pr_auc", "f1_max_reference")
    } == {".3f"}
    assert {spec_for(k) for k in ("improvement_t_pct", "kf_improvement_r_pct")} == {".1f"}
    assert {spec_for(k) for k in ("memory_mib", "rss_growth_mib", "time_s")} == {".2f"}


def test_seed_ranks_tie_values_equal_at_their_displayed_precision():
    """QA M1: floating-point noise below a metric's displayed decimals must not decide a rank."""
    from msa_slam.evaluation.display import spec_for
    from msa_slam.evaluation.spread import seed_ranks

    pr = {"msa": 0.9999999999999999, "all": 1.0, "entropy": 0.998}
    assert seed_ranks(pr, True) == {"msa": 2, "all": 1, "entropy": 3}  # raw floats: noise ranks
    assert seed_ranks(pr, True, spec_for("pr_auc")) == {"msa": 1, "all": 1, "entropy": 3}  # ties share the best
    ate = {"msa": 0.412000003, "all": 0.412, "constant-1m": 0.4136}
    assert seed_ranks(ate, False, spec_for("ate_after_m")) == {"msa": 1, "all": 1, "constant-1m": 3}
    improvement = {"msa": -1e-11, "all": 2e-12, "entropy": 0.06}  # -0.0 and 0.0 at .1f: equal
    assert seed_ranks(improvement, True, spec_for("improvement_t_pct")) == {"msa": 2, "all": 2, "entropy": 1}


def test_seed_summary_ranks_at_each_metrics_displayed_precision():
    from msa_slam.experiments.seeds import seed_summary

    rows = {
        0: [
            seed_row("msa", pr_auc=0.9999999999999999, ate_after_m=0.412000003),
            seed_row("all", pr_auc=1.0, ate_after_m=0.412),
            seed_row("entropy", pr_auc=0.5, ate_after_m=0.5),
        ]
    }
    metrics = seed_summary(rows).metrics
    assert {m: e.ranks for m, e in metrics["pr_auc"].methods.items()} == {"msa": [1], "all": [1], "entropy": [3]}
    assert {m: e.ranks for m, e in metrics["ate_after_m"].methods.items()} == {"msa": [1], "all": [1], "entropy": [3]}
    assert metrics["pr_auc"].methods["msa"].values == [0.9999999999999999]  # the values stay as measured


def test_ate_difference_figure_labels_its_reference(tmp_path, monkeypatch):
    """QA M9: after `report --reference msa` the y axis must not still read ATE(all)."""
    import msa_slam.viz.experiment_figures as figures

    labels = []
    real = figures._save

    def recording(fig, path):
        labels.append(fig.axes[0].get_ylabel())
        return real(fig, path)

    monkeypatch.setattr(figures, "_save", recording)
    figures.plot_ate_difference(
        tmp_path / "msa.png",
        {"all": [0.1, 0.3, -0.05], "entropy": [0.02, -0.1, 0.0]},
        title="ATE after optimisation minus msa",
        reference="msa",
    )
    figures.plot_ate_difference(tmp_path / "all.png", {"msa": [-0.1]})
    assert labels == ["ATE - ATE(msa) [m]", "ATE - ATE(all) [m]"]
    assert (tmp_path / "msa.png").is_file()
