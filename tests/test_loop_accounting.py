"""Loop accounting (evaluation/loops.py): constructed poses and loops with known counts and recalls, and one
compare on the small simulated sequence whose table must carry the columns, consistent with each other."""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest
from helpers.metrics import stored_metrics
from scipy.spatial.transform import Rotation

from msa_slam.evaluation.loops import (
    FALSE_LOOP_ANGLE_DEG,
    NO_GROUND_TRUTH,
    account_loops,
    is_false_loop,
    relative_pose_error,
    revisit_pairs,
)
from msa_slam.evaluation.metrics import Unavailable
from msa_slam.evaluation.metrics_json import from_json
from msa_slam.evaluation.metrics_writer import to_json
from msa_slam.experiments.compare import run_compare
from msa_slam.pipeline import make_config
from msa_slam.reporting.comparison import COLUMNS, REJECTED_COLUMNS
from msa_slam.slam.loop_closing import REJECTION_REASONS
from msa_slam.types import LoopClosure
from msa_slam.viz.labels import counted

RADIUS, MIN_TRAVEL = 3.0, 30.0
# Out along x and back 0.5 m beside the way out: path 0, 10, 20, 50, 80, 90, 100 m; frames 4, 5, 6 come back
# to 2, 1, 0 (0.5 m apart), 60, 80 and 100 m of path later.
XS = [0.0, 10.0, 20.0, 50.0, 20.5, 10.5, 0.5]


def _poses(xs, yaws_deg=None) -> np.ndarray:
    poses = np.tile(np.eye(4), (len(xs), 1, 1))
    poses[:, 0, 3] = xs
    for pose, yaw in zip(poses, yaws_deg or [0.0] * len(xs)):
        pose[:3, :3] = Rotation.from_euler("z", yaw, degrees=True).as_matrix()
    return poses


def _loop(gt, match, query, rejected="", accepted=False, verified=True, error=None) -> LoopClosure:
    """A loop record as loop closing makes it; `error` (4x4) is applied to the true relative pose to make the
    measured one of an accepted loop."""
    T_true = np.linalg.inv(gt[match]) @ gt[query]
    measured = T_true @ (np.eye(4) if error is None else error) if accepted else None
    distance = float(np.linalg.norm(gt[query, :3, 3] - gt[match, :3, 3]))
    return LoopClosure(
        query, match, 0.9, distance, verified=verified, accepted=accepted, T_match_query=measured, rejected=rejected
    )


def _shift(x=0.0, yaw_deg=0.0) -> np.ndarray:
    error = np.eye(4)
    error[0, 3] = x
    error[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    return error


def test_revisit_pairs_need_the_radius_and_the_path():
    gt = _poses(XS)
    every = np.arange(len(XS))
    assert revisit_pairs(every, gt, RADIUS, MIN_TRAVEL) == {(2, 4), (1, 5), (0, 6)}
    assert revisit_pairs(every, gt, RADIUS, 70.0) == {(1, 5), (0, 6)}  # frames 2 and 4: 60 m of path apart
    assert revisit_pairs(every, gt, 0.4, MIN_TRAVEL) == set()  # each return is 0.5 m off the way out
    # the path runs over every frame, keyframes or not: without frame 5, frames 1 and 6 are still 90 m apart
    assert revisit_pairs(np.array([0, 1, 2, 3, 4, 6]), gt, RADIUS, MIN_TRAVEL) == {(2, 4), (0, 6)}
    assert revisit_pairs(np.array([3]), gt, RADIUS, MIN_TRAVEL) == set()


def test_accounting_counts_candidates_rejections_false_loops_and_recall():
    gt = _poses(XS, yaws_deg=[0, 0, 0, 0, 180, 180, 90])  # turned on the way back: relative poses are not shifts
    loops = [
        _loop(gt, 2, 4, accepted=True),  # a revisit closed with the right pose
        _loop(gt, 0, 6, accepted=True, error=_shift(x=4.0)),  # a revisit closed 4 m off: false, still closed
        _loop(gt, 1, 5, rejected="overlap"),  # a revisit rejected
        _loop(gt, 1, 4, accepted=True, error=_shift(yaw_deg=FALSE_LOOP_ANGLE_DEG + 1)),  # 10.5 m apart, wrong turn
        _loop(gt, 0, 5, accepted=True, error=_shift(x=2.9, yaw_deg=FALSE_LOOP_ANGLE_DEG - 1)),  # within both limits
        _loop(gt, 0, 4, rejected="drift"),
        _loop(gt, 3, 6, rejected="sparse"),
        _loop(gt, 0, 3, verified=False),  # oracle mode: a far candidate is not registered
    ]
    acc, why = account_loops(loops, np.arange(len(XS)), gt, RADIUS, MIN_TRAVEL, REJECTION_REASONS)
    assert (acc.candidates, acc.registered, acc.accepted) == (8, 7, 4)
    assert acc.rejected == {**dict.fromkeys(REJECTION_REASONS, 0), "sparse": 1, "overlap": 1, "drift": 1}
    assert acc.accepted + sum(acc.rejected.values()) == acc.registered
    assert acc.true_candidates == 3  # (2, 4), (0, 6), (1, 5): 0.5 m apart
    assert acc.false_loops == 2  # (0, 6) by its shift, (1, 4) by its rotation; (0, 5) is within both
    assert acc.distant_loops == 2  # (1, 4) and (0, 5): 10.5 m apart, whether their pose is right or not
    assert (acc.revisits, acc.revisits_closed, acc.revisit_recall) == (3, 2, pytest.approx(2 / 3))
    assert (acc.revisit_keyframes, acc.revisit_keyframes_closed) == (3, 2)
    assert why == {}


def test_metrics_json_counts_wrong_poses_as_false_and_far_keyframes_as_distant():
    """metrics.json's `false_loops` is about the measured pose, not how far apart the keyframes are: (a) keyframes
    10 m apart registered to their true pose is distant, not false; (b) keyframes 1 m apart registered 4 m off and
    (c) 10 deg off are false."""
    gt = _poses([0.0, 10.0, 1.0, 1.0, 0.0], yaws_deg=[0, 0, 0, 30, 0])
    loops = [
        _loop(gt, 0, 1, accepted=True),  # (a)
        _loop(gt, 0, 2, accepted=True, error=_shift(x=4.0)),  # (b)
        _loop(gt, 0, 3, accepted=True, error=_shift(yaw_deg=10.0)),  # (c)
    ]
    acc, _ = account_loops(loops, np.arange(len(gt)), gt, RADIUS, MIN_TRAVEL, REJECTION_REASONS)
    stored = from_json(stored_metrics("batch.json"), "batch.json")
    m = to_json(replace(stored, loops=replace(stored.loops, accounting=acc)))
    assert m["false_loops"] == 2 and m["loop_accounting"]["distant_loops"] == 1
    assert "false_accepted" not in m["loop_accounting"] and "false_loops" not in m["loop_accounting"]  # one key
    again = from_json(m, "metrics.json").loops
    assert (again.false_loops, again.accounting.distant_loops) == (2, 1)
    row = from_json(m, "metrics.json").comparison_row(REJECTION_REASONS)
    assert (row.value("false_loops"), row.value("distant_loops")) == (2, 1)


def test_pair_recall_and_keyframe_recall_differ_on_dense_keyframes():
    """Two older keyframes within the radius of one newer one: one accepted loop closes one pair of two, and
    the newer keyframe's revisit."""
    gt = _poses([0.0, 1.0, 50.0, 0.5])  # frames 0 and 1 are 1 m of path apart: no revisit of each other
    acc, _ = account_loops([_loop(gt, 0, 3, accepted=True)], np.arange(4), gt, RADIUS, MIN_TRAVEL, REJECTION_REASONS)
    assert (acc.revisits, acc.revisits_closed, acc.revisit_recall) == (2, 1, 0.5)
    assert (acc.revisit_keyframes, acc.revisit_keyframes_closed, acc.revisit_keyframe_recall) == (1, 1, 1.0)


def test_a_loop_away_from_the_revisits_closes_none():
    gt = _poses(XS)
    acc, _ = account_loops(
        [_loop(gt, 1, 4, accepted=True)], np.arange(len(XS)), gt, RADIUS, MIN_TRAVEL, REJECTION_REASONS
    )
    assert (acc.revisits, acc.revisits_closed, acc.revisit_recall, acc.revisit_keyframe_recall) == (3, 0, 0.0, 0.0)
    assert acc.true_candidates == 0 and acc.false_loops == 0  # its measured pose is the true one
    assert acc.distant_loops == 1  # 10.5 m apart in ground truth


def test_without_ground_truth_only_the_counts_are_given():
    gt = _poses(XS)
    loops = [_loop(gt, 2, 4, accepted=True), _loop(gt, 1, 5, rejected="residual")]
    for missing in (None, np.full_like(gt, np.nan)):
        acc, why = account_loops(loops, np.arange(len(XS)), missing, RADIUS, MIN_TRAVEL, REJECTION_REASONS)
        assert (acc.candidates, acc.registered, acc.accepted, acc.rejected["residual"]) == (2, 2, 1, 1)
        gone = (acc.true_candidates, acc.false_loops, acc.distant_loops, acc.revisit_recall, acc.revisits)
        assert gone == (Unavailable(NO_GROUND_TRUTH),) * 5
        assert why == {"loop_truth": NO_GROUND_TRUTH}


def test_no_revisit_leaves_the_recall_unavailable():
    gt = _poses(np.arange(10) * 5.0)  # a straight line
    acc, why = account_loops([], np.arange(10), gt, RADIUS, MIN_TRAVEL, REJECTION_REASONS)
    assert "no revisit" in why["revisit_recall"]
    assert acc.revisits == 0 and acc.revisit_recall == acc.revisit_keyframe_recall == Unavailable(why["revisit_recall"])


def test_relative_pose_error_and_false_loop_limits():
    T = _poses([3.0], [30.0])[0]
    shift, angle = relative_pose_error(T @ _shift(x=3.0, yaw_deg=-5.0), T)
    assert shift == pytest.approx(3.0) and angle == pytest.approx(5.0)
    gt = _poses([0.0, 40.0, 1.0])
    assert not is_false_loop(_loop(gt, 0, 2, accepted=True, error=_shift(x=3.0)), gt, RADIUS)  # at the limit
    assert is_false_loop(_loop(gt, 0, 2, accepted=True, error=_shift(x=3.01)), gt, RADIUS)
    with pytest.raises(ValueError, match="no measured relative pose"):
        is_false_loop(LoopClosure(2, 0, 0.9, 1.0, verified=True, accepted=True), gt, RADIUS)


# End to end: the small simulated figure-eight (conftest: sim "test", odometry with a known drift), realistic mode
# with a low similarity threshold so that candidates are registered, and the residual gate (no drift check: the
# fixture's drift exceeds the drift model's allowance) accepts the true ones and rejects others.
LOOSE = {
    "similarity_threshold": 0.4,
    "min_travel_m": 0.0,
    "mode": "realistic",
    "drift_check": "off",
    "verifier": {"max_residual": 0.3, "min_inliers": 1, "min_inlier_fraction": 0.0},
}


def test_compare_reports_the_loop_accounting(sequence, odometry_file, cache_dir, tmp_path):
    base = make_config(
        dataset=str(sequence), odometry=str(odometry_file), cache_dir=str(cache_dir), sampler="msa", **LOOSE
    )
    methods = (("constant-3m", "constant", {"distance": 3.0}), ("msa", "msa", {}))
    folder = run_compare(base, tmp_path / "cmp", methods=methods, sweep=False, figures=False).parent
    rows = list(csv.DictReader(open(folder / "comparison.csv")))
    assert list(rows[0]) == list(COLUMNS) and [r["method"] for r in rows] == ["constant-3m", "msa"]
    for row in rows:
        m = json.loads((folder / "runs" / row["method"] / "metrics.json").read_text())
        acc = m["loop_accounting"]
        count = {
            c: int(row[c])
            for c in (
                "candidates",
                "true_candidates",
                "verified",
                "rejected",
                *REJECTED_COLUMNS,
                "false_loops",
                "distant_loops",
                "revisits",
            )
        }
        assert count["candidates"] == acc["registered"] == m["registrations"] > 0  # realistic: all registered
        assert count["verified"] + count["rejected"] == acc["registered"]
        assert sum(count[c] for c in REJECTED_COLUMNS) == count["rejected"]
        assert count["true_candidates"] <= count["candidates"]
        assert count["false_loops"] == m["false_loops"] and count["distant_loops"] == acc["distant_loops"]
        with open(folder / "runs" / row["method"] / "loops.csv") as handle:
            loops = list(csv.DictReader(handle))
        accepted = [r for r in loops if int(r["accepted"])]
        assert len(accepted) == count["verified"]
        assert sum(int(r["false_loop"]) for r in loops) == count["false_loops"]  # only accepted loops are false
        assert sum(float(r["gt_distance_m"]) > base.loop_radius for r in accepted) == count["distant_loops"]
        assert sum(float(r["gt_distance_m"]) <= base.loop_radius for r in loops) == count["true_candidates"]
        assert count["revisits"] > 0  # the figure-eight crosses itself
        assert float(row["revisit_recall"]) == pytest.approx(acc["revisits_closed"] / acc["revisits"])
        assert acc["revisits_closed"] <= count["verified"]
    assert any(int(r["rejected"]) > 0 for r in rows) and any(int(r["verified"]) > 0 for r in rows)
    report = (folder / "report.md").read_text()
    assert "| true cand. | verified | rejected | rej. sparse |" in report and "revisit recall" in report
    msa = json.loads((folder / "runs" / "msa" / "metrics.json").read_text())["loop_accounting"]
    assert (
        f"Loop accounting: {msa['registered']} of {counted(msa['candidates'], 'candidate')} registered, "
        f"{msa['accepted']} accepted"
    ) in (folder / "runs" / "msa" / "report.md").read_text()
