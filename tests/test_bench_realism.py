"""benchmarks/bench_realism.py: how its targets score all samples' PR-AUC where the package's metric says n/a
because every recorded match is true, on constructed matches (the runs themselves are the pipeline's)."""

from __future__ import annotations

import pytest
from helpers.benchmarks import loaded_benchmark

from msa_slam.place_recognition import precision_recall


@pytest.fixture(scope="module")
def bench():
    yield from loaded_benchmark("bench_realism")


def test_all_true_matches_score_the_trapezoid_over_precision_one(bench):
    curve = precision_recall([0.95, 0.85, 0.7, 0.6], [0.5, 1.0, 2.0, 2.9])
    assert curve.auc is None and "precision is 1 by construction" in curve.unavailable
    assert bench.perfect_precision_auc(curve) == pytest.approx(1.0)  # no match reaches 0.99: recall 1 -> 0
    assert bench.recall_at(curve, 0.8) == pytest.approx(0.5)
    high = precision_recall([0.995, 0.9], [0.5, 1.0])  # half the recall is still there at 0.99
    assert bench.perfect_precision_auc(high) == pytest.approx(0.5)


def test_other_curves_keep_the_metric_or_stay_undefined(bench):
    mixed = precision_recall([0.9, 0.85, 0.5], [1.0, 10.0, 2.0])  # a wrong match: the metric's own value
    assert mixed.auc is not None and bench.perfect_precision_auc(mixed) is None
    no_revisit = precision_recall([0.9, 0.5], [10.0, 20.0])
    assert bench.perfect_precision_auc(no_revisit) is None and bench.recall_at(no_revisit, 0.8) is None
    assert bench.perfect_precision_auc(None) is None
    row = {"auc_all": None, "auc_all_perfect": 1.0, "auc_c2": 0.9}
    assert bench._scored(row, "auc_all") == 1.0 and bench._scored(row, "auc_c2") == 0.9
    assert bench._auc_all(row) == "100.0*"
    assert "constant 2 m >= 5 points below all samples on 1 of 1" in bench._auc_targets(
        {"05": [{**row, "auc_all_why": "precision is 1 by construction"}]}, "auc_all", "auc_c2"
    )


def test_drift_is_split_into_horizontal_and_vertical_parts(bench):
    import numpy as np

    gt = np.tile(np.eye(4), (301, 1, 1))
    gt[:, 0, 3] = np.arange(301.0)  # 300 m straight ahead, 1 m a frame
    climbing, veering = gt.copy(), gt.copy()
    climbing[:, 2, 3] += 0.01 * gt[:, 0, 3]  # 1 % up
    veering[:, 1, 3] += 0.02 * gt[:, 0, 3]  # 2 % sideways
    total, horizontal, vertical = bench.relative_translation_error(gt, climbing)
    assert total == pytest.approx(1.0, abs=0.01) and horizontal < 0.01 and vertical == pytest.approx(1.0, abs=0.01)
    total, horizontal, vertical = bench.relative_translation_error(gt, veering)
    assert horizontal == pytest.approx(2.0, abs=0.01) and vertical < 0.01
    assert bench._rte_mean_std([(1.0, 0.5, 0.8), (2.0, 1.5, 1.2)]) == ["1.50 +- 0.71", "1.00 +- 0.71", "1.00 +- 0.28"]
    assert bench._rte_mean_std([(1.0, 0.5, 0.8), None]) == ["n/a"] * 3


def test_pitch_drift_is_the_signed_pitch_error_per_100_m(bench):
    import numpy as np
    from scipy.spatial.transform import Rotation

    gt = np.tile(np.eye(4), (301, 1, 1))
    gt[:, 0, 3] = np.arange(301.0)  # 300 m straight ahead, 1 m a frame
    nose_up = gt.copy()
    # the estimate's forward axis turns up by 0.5 deg per 100 m (a rotation about y by minus the angle)
    nose_up[:, :3, :3] = Rotation.from_euler("y", -np.radians(0.005) * gt[:, 0, 3, None]).as_matrix()
    assert bench.pitch_drift(gt, nose_up) == pytest.approx(0.5, rel=1e-6)
    nose_down = gt.copy()
    nose_down[:, :3, :3] = np.linalg.inv(nose_up[:, :3, :3])
    assert bench.pitch_drift(gt, nose_down) == pytest.approx(-0.5, rel=1e-6)
    assert bench.pitch_drift(gt, gt) == 0.0
    assert bench.pitch_drift(gt[:50], nose_up[:50]) is None  # 49 m: shorter than the shortest segment


def test_a_row_simulates_the_frames_from_start(bench):
    from msa_slam.sources import parse_spec

    spec = bench.dataset_spec("09", 1, "kitti", start=600, frames=300, azimuth_steps=720)
    assert spec == "sim:kitti-09,seed=1,realism=kitti,start=600,end=900,azimuth_steps=720"
    config = parse_spec(spec).config
    assert (config.start, config.end, config.frame_count()) == (600, 900, 300)
    assert bench.dataset_spec("07", 0, "kitti", frames=400) == "sim:kitti-07,seed=0,realism=kitti,end=400"
    assert bench.dataset_spec("00", 2, "clean") == "sim:kitti-00,seed=2,realism=clean"
