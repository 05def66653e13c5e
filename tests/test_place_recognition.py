"""Keyframe database searches and precision/recall metrics on constructed cases."""

from __future__ import annotations

import re

import numpy as np
import pytest

from msa_slam.descriptors import ScanContext
from msa_slam.errors import InputError
from msa_slam.place_recognition import ExtraFrame, KeyframeDatabase, precision_recall
from msa_slam.place_recognition.figures import plot_pr_curves


def pose_at(x: float, y: float = 0.0) -> np.ndarray:
    pose = np.eye(4)
    pose[:2, 3] = (x, y)
    return pose


class Scalar:
    """1-D toy descriptor: similarity 1/(1+|a-b|), to make expected matches obvious."""

    name = "scalar"

    def compute(self, points, frame=None):
        return np.asarray([float(frame)])

    def similarity_many(self, query, bank):
        return 1.0 / (1.0 + np.abs(np.asarray(bank)[:, 0] - np.asarray(query)[0]))

    def similarity(self, a, b):
        return float(self.similarity_many(a, np.asarray(b)[None])[0])


@pytest.fixture
def scalar_db():
    db = KeyframeDatabase(Scalar())
    for i in range(0, 100, 10):  # keyframes 0, 10, ..., 90 with descriptor value i
        db.add(i, pose_at(i), np.array([float(i)]))
    return db


def test_query_threshold_topk_and_exclusion(scalar_db):
    hits = scalar_db.query(95, np.array([41.0]), pose_at(40.0, 3.0), threshold=0.0, top_k=3)
    assert [m.keyframe_id for m in hits] == [40, 50, 30]
    assert hits[0].similarity == pytest.approx(0.5) and hits[0].distance == pytest.approx(3.0)
    assert scalar_db.query(95, np.array([41.0]), threshold=0.8) == []  # best is 0.5
    # default: any older keyframe (40 < 45); frame-window exclusion: 45 - id > 10, i.e. 0..30
    assert scalar_db.query(45, np.array([41.0]), threshold=0.0)[0].keyframe_id == 40
    assert scalar_db.query(45, np.array([41.0]), threshold=0.0, exclude_frames=10)[0].keyframe_id == 30
    # count exclusion: the 6 newest (40..90) are left out
    assert scalar_db.query(200, np.array([41.0]), threshold=0.0, exclude_recent=6)[0].keyframe_id == 30
    assert np.isnan(scalar_db.query(200, np.array([41.0]), threshold=0.0)[0].distance)


def test_memory_accounting(scalar_db):
    assert scalar_db.bytes_per_keyframe == 8 + 128 + 8  # id + 4x4 pose + 1 float
    assert scalar_db.nbytes == 10 * 144
    sc_db = KeyframeDatabase(ScanContext())
    sc_db.add(0, np.eye(4), np.zeros((20, 60)))
    assert sc_db.bytes_per_keyframe == 8 + 128 + 20 * 60 * 8 + 20 * 8  # + ring key


def test_reference_protocol(scalar_db):
    # nearest 3 keyframes to x=62 are 60, 70, 50; best descriptor match to 48 among them is 50
    m = scalar_db.query_reference(100, pose_at(62.0), np.array([48.0]), n_nearest=3)
    assert (m.keyframe_id, m.similarity, m.distance) == (50, pytest.approx(1 / 3), pytest.approx(12.0))
    # keyframe 20 matches better but is not among the pose neighbours
    assert scalar_db.query_reference(100, pose_at(62.0), np.array([20.0]), n_nearest=3).keyframe_id == 50
    # an extra candidate (e.g. an MSA window member) that matches better wins
    extra = [ExtraFrame(75, pose_at(75.0), np.array([48.0]))]
    m = scalar_db.query_reference(100, pose_at(62.0), np.array([48.0]), n_nearest=3, extra=extra)
    assert (m.keyframe_id, m.similarity, m.distance) == (75, 1.0, pytest.approx(13.0))
    # match not more than 10 frames away -> nothing recorded
    assert scalar_db.query_reference(60, pose_at(62.0), np.array([50.0]), n_nearest=3) is None
    assert scalar_db.query_reference(61, pose_at(62.0), np.array([50.0]), n_nearest=3).keyframe_id == 50


def _random_walk_sc(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = rng.normal(0, 0.3, (n, 20, 60))
    return np.abs(np.cumsum(steps, axis=0) + 3.0)


def test_two_stage_finds_revisits_like_exhaustive():
    sc = ScanContext()
    bank = _random_walk_sc(600, 0)
    db = KeyframeDatabase(sc, search="two_stage", n_candidates=10, rebuild_every=50)
    for i, d in enumerate(bank):
        db.add(i, np.eye(4), d)
    rng = np.random.default_rng(1)
    for target in (3, 250, 590, 599):  # 599: added after the last tree build, still found
        query = np.roll(bank[target] + rng.normal(0, 0.05, (20, 60)), 7, axis=1)
        two = db.query(10_000, query, threshold=0.0)[0]
        full = db.query(10_000, query, threshold=0.0, search="exhaustive")[0]
        assert two.keyframe_id == full.keyframe_id == target
        assert two.similarity == pytest.approx(full.similarity, abs=1e-12)
    # enough stage-1 neighbours make two-stage exhaustive
    noisy = bank[123] + np.random.default_rng(5).normal(0, 1.0, (20, 60))
    wide = db.query(10_000, noisy, threshold=0.0, top_k=5, n_candidates=600)
    full = db.query(10_000, noisy, threshold=0.0, top_k=5, search="exhaustive")
    assert [(m.keyframe_id, m.similarity) for m in wide] == [(m.keyframe_id, m.similarity) for m in full]
    # exclusion applies in both stages
    query = bank[590]
    assert db.query(600, query, threshold=0.0, exclude_frames=20)[0].keyframe_id < 580


def test_auto_search_switches_to_two_stage():
    db = KeyframeDatabase(ScanContext(), two_stage_min_size=5)
    assert not db._uses_two_stage(None)
    for i, d in enumerate(_random_walk_sc(5, 2)):
        db.add(i, np.eye(4), d)
    assert db._uses_two_stage(None)
    assert not KeyframeDatabase(Scalar(), two_stage_min_size=0)._uses_two_stage(None)


def test_database_errors():
    with pytest.raises(InputError, match="search must be one of"):
        KeyframeDatabase(ScanContext(), search="fast")
    with pytest.raises(InputError, match="no search key"):
        KeyframeDatabase(Scalar(), search="two_stage")
    db = KeyframeDatabase(ScanContext())
    db.add(0, np.eye(4), np.zeros((20, 60)))
    with pytest.raises(InputError, match=r"keyframe 1: descriptor shape \(20, 59\)"):
        db.add(1, np.eye(4), np.zeros((20, 59)))
    with pytest.raises(InputError, match="keyframe 3: descriptor has NaN"):
        db.add(3, np.eye(4), np.full((20, 60), np.nan))
    with pytest.raises(InputError, match="keyframe 2 pose"):
        db.add(2, np.zeros((4, 4)), np.zeros((20, 60)))


def test_precision_recall_hand_computed():
    # matches: (sim, dist) = (0.9, 1 m) TP-able, (0.5, 1 m) TP-able, (0.95, 10 m) false
    curve = precision_recall([0.9, 0.5, 0.95], [1.0, 1.0, 10.0])
    t = {round(v, 2): i for i, v in enumerate(curve.thresholds)}
    assert len(curve.thresholds) == 100 and curve.thresholds[-1] == 0.99
    # thr 0.00..0.50: TP 2, FP 1, FN 0 -> P 2/3, R 1
    assert curve.precision[t[0.5]] == pytest.approx(2 / 3) and curve.recall[t[0.5]] == 1.0
    # thr 0.51..0.90: TP 1, FP 1, FN 1 -> P 1/2, R 1/2
    assert curve.precision[t[0.9]] == 0.5 and curve.recall[t[0.9]] == 0.5
    # thr 0.91..0.94: TP 0, FP 1 -> P 0, R 0, F1 0
    assert curve.precision[t[0.93]] == 0.0 and curve.f1[t[0.93]] == 0.0
    # thr 0.95: the reference counts FP only when sim > thr -> nothing predicted -> P 1, R 0
    assert curve.precision[t[0.95]] == 1.0 and curve.recall[t[0.95]] == 0.0
    assert precision_recall([0.9, 0.5, 0.95], [1, 1, 10], strict_false_positive=False).precision[t[0.95]] == 0.0
    assert curve.f1_max == pytest.approx(0.8) and curve.f1_max_threshold == 0.0
    # area: recall drops 1 -> 0.5 between thr 0.50 and 0.51 (P 2/3 -> 1/2), 0.5 -> 0 at 0.91 (P 1/2 -> 0)
    assert curve.auc == pytest.approx(0.5 * (2 / 3 + 0.5) / 2 + 0.5 * 0.5 / 2)


def test_precision_recall_distance_gate_and_errors():
    assert precision_recall([0.9], [3.0]).recall[0] == 1.0
    assert precision_recall([0.9], [3.0], max_distance=2.9).recall[0] == 0.0
    with pytest.raises(InputError, match="2 similarities but 1 distances"):
        precision_recall([0.1, 0.2], [1.0])


def test_pr_figure_written(tmp_path):
    curve = precision_recall([0.9, 0.5, 0.95], [1.0, 1.0, 10.0])
    out = plot_pr_curves({"MSA": curve, "all": curve}, tmp_path / "figs" / "pr.png")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    assert [p.name for p in (tmp_path / "figs").iterdir()] == ["pr.png"]


def test_query_with_no_eligible_keyframe_returns_nothing():
    db = KeyframeDatabase(ScanContext())
    desc = np.ones((20, 60))
    other = np.zeros((20, 60))
    other[:, :5] = 1.0
    db.add(0, np.eye(4), other)
    db.add(1, np.eye(4), desc)
    assert db.query(2, desc, exclude_frames=5) == []
    assert db.query(2, desc, exclude_recent=2) == []
    assert [m.keyframe_id for m in db.query(9, desc, exclude_frames=5)] == [1]


@pytest.mark.parametrize(
    "sims, dists, reason",
    [
        ([0.9, 0.5, 0.3], [10.0, 20.0, 5.0], "no best match of the 3 queries lies within 3 m.*recall is undefined"),
        (
            [0.9, 0.5],
            [1.0, 2.0],
            "the best match of each of the 2 queries lies within 3 m.*precision is 1 by construction",
        ),
        ([-0.5, -0.2], [1.0, 10.0], "no match reached the lowest similarity threshold"),
        ([], [], "no loop query had a match to score"),
    ],
    ids=["no-revisit", "only-revisits", "below-thresholds", "empty"],
)
def test_uninformative_pr_metrics_are_none_with_reason(sims, dists, reason):
    curve = precision_recall(sims, dists)
    assert curve.auc is None and curve.f1_max is None and curve.f1_max_threshold is None
    assert re.fullmatch(reason, curve.unavailable)
    assert curve.as_dict()["unavailable"] == curve.unavailable
    assert len(curve.precision) == len(curve.thresholds) == 100  # the curve itself is still there


def test_informative_pr_metrics_have_no_reason_and_no_negative_zero():
    curve = precision_recall([0.9, 0.5, 0.95], [1.0, 1.0, 10.0])
    assert curve.unavailable is None and curve.auc > 0
    # recall stays 1 over both thresholds: zero area, which the trapezoid over falling recall signs negative
    worst = precision_recall([0.9, 0.95], [1.0, 10.0], thresholds=[0.0, 0.5])
    assert worst.auc == 0.0 and str(worst.auc) == "0.0"
