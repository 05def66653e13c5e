"""Loops the batch graph uses: the pairwise-consistent set, decided before optimisation, optimised in full;
the drift gate of loop closing against the odometry covariance accumulated along the path.

A constructed drive: a 100 m x 60 m rectangle in 2 m steps, then its first 40 m again (a revisit). The
odometry turns 0.1 deg too far and runs 1 % long every step, so at the revisit it is ~16 m off, far beyond
what the graph's drift model expects over that path (as KISS-ICP on a hilly sequence). True loops join
revisit frames to the first visit with the ground-truth transform; wrong loops claim a revisit frame is at a
first-visit frame it is not (perceptual aliasing: the true loop's transform, attached to the wrong frame).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import drifted
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from msa_slam.backend import GraphConfig, PoseGraph
from msa_slam.backend.inliers import LoopEdge, pair_chi2, select_inliers, single_chi2
from msa_slam.backend.noise import PathCovariance, chi2_quantile
from msa_slam.errors import InputError
from msa_slam.evaluation import ate

STEP = 2.0
SIDES = (50, 30, 50, 30)  # steps per side of the rectangle
REVISIT = 20  # steps driven again along the first side
LOOP_COV = np.diag(np.repeat([math.radians(0.25), 0.05], 3) ** 2)
# The graph's drift model: 2 % of the distance and 2 deg per 100 m, calibrated over 100 m
CONFIG = GraphConfig(drift_translation=0.02, drift_rotation=math.radians(2) / 100, loop_inliers="consistent")
LAP = sum(SIDES)


def _drive() -> np.ndarray:
    """Ground truth: the rectangle (left turns), then REVISIT steps along its first side again."""
    move, turn = np.eye(4), np.eye(4)
    move[0, 3] = STEP
    turn[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    poses, pose = [np.eye(4)], np.eye(4)
    for side in SIDES:
        for _ in range(side):
            pose = pose @ move
            poses.append(pose)
        pose = pose @ turn
        poses[-1] = pose
    for _ in range(REVISIT):
        pose = pose @ move
        poses.append(pose)
    return np.stack(poses)


def _odometry(gt: np.ndarray) -> np.ndarray:
    """0.1 deg too far and 1 % too long every step (conftest.drifted)."""
    return drifted(gt, math.radians(0.1), 1.01)


@pytest.fixture(scope="module")
def drive() -> tuple[np.ndarray, np.ndarray]:
    gt = _drive()
    return gt, _odometry(gt)


def _true(gt: np.ndarray, steps: int) -> tuple[int, int, np.ndarray]:
    """The loop from revisit step `steps` back to the same place on the first visit."""
    target, source = steps, LAP + steps
    return target, source, np.linalg.inv(gt[target]) @ gt[source]


def _wrong(gt: np.ndarray, steps: int, offset: int) -> tuple[int, int, np.ndarray]:
    """Revisit step `steps` matched to the first-visit frame `offset` steps further on, with the transform of
    the true place: the loop says the two frames are where they are not, by offset x STEP metres."""
    target, source, measured = _true(gt, steps)
    return target + offset, source, measured


def _graph(
    odom: np.ndarray, loops: list[tuple[int, int, np.ndarray]], config: GraphConfig = CONFIG, mode: str = "realistic"
) -> PoseGraph:
    graph = PoseGraph(config, mode=mode)
    for k, pose in enumerate(odom):
        graph.add_keyframe(k, pose)
    for target, source, measured in loops:
        graph.add_loop(target, source, measured, LOOP_COV)
    return graph


def _relative_error(poses: np.ndarray, gt: np.ndarray, a: int, b: int) -> float:
    """Translation error of the relative pose between frames a and b."""
    rel, true = np.linalg.inv(poses[a]) @ poses[b], np.linalg.inv(gt[a]) @ gt[b]
    return float(np.linalg.norm((np.linalg.inv(true) @ rel)[:3, 3]))


def test_the_constructed_drift_is_large(drive):
    gt, odom = drive
    assert _relative_error(odom, gt, 0, LAP) > 15.0  # metres between the revisit and its first visit


def test_wrong_loops_are_excluded_and_true_ones_close_the_drift(drive):
    gt, odom = drive
    true_loops = [_true(gt, 2), _true(gt, 12)]
    wrong_loops = [_wrong(gt, 5, 15), _wrong(gt, 8, -6), _wrong(gt, 16, 40)]
    graph = _graph(odom, [true_loops[0], wrong_loops[0], true_loops[1], wrong_loops[1], wrong_loops[2]])
    optimised = graph.optimize()
    assert graph.inliers.kept == (0, 2) and graph.dropped_loops == (1, 3, 4)
    assert graph.inliers.method == "exact" and graph.kernel == "none"
    # the known answer: the optimum of the graph with the true loops alone
    np.testing.assert_allclose(optimised, _graph(odom, true_loops).optimize(), atol=1e-9)
    for target, source, _ in true_loops:  # the loops' frames end where ground truth has them
        assert _relative_error(odom, gt, target, source) > 10.0
        assert _relative_error(optimised, gt, target, source) < 0.05
    # the whole trajectory: the odometry's bias bends every side, which two loops at the revisit cannot unbend
    before, after = ate(odom, gt).translation_rmse, ate(optimised, gt).translation_rmse
    assert before > 4.0 and after < 0.15 * before
    # g2o export: the dropped loops are not among the factors the optimiser used
    assert graph.factors.size() == len(odom) + 2
    description = graph.describe()
    assert description["inlier_selection"]["dropped"] == 3 and description["loop_inliers"] == "consistent"


def test_every_loop_with_the_cauchy_kernel_is_pulled_by_the_wrong_ones(drive):
    """The behaviour the selection replaces: all loops, Cauchy kernel on whitened residuals."""
    gt, odom = drive
    loops = [_true(gt, 2), _wrong(gt, 5, 15), _true(gt, 12), _wrong(gt, 8, -6), _wrong(gt, 16, 40)]
    consistent = ate(_graph(odom, loops).optimize(), gt).translation_rmse
    cauchy = _graph(odom, loops, CONFIG.model_copy(update={"loop_inliers": "all", "robust": "cauchy"}))
    assert cauchy.inliers is None and cauchy.kernel == "cauchy"
    assert ate(cauchy.optimize(), gt).translation_rmse > 2 * consistent


def test_a_single_true_loop_correcting_large_drift_is_used_in_full(drive):
    gt, odom = drive
    target, source, measured = _true(gt, 0)
    before = _relative_error(odom, gt, target, source)
    graph = _graph(odom, [(target, source, measured)])
    after = _relative_error(graph.optimize(), gt, target, source)
    assert graph.inliers.kept == (0,) and graph.inliers.method == "single"
    assert after < 0.01 * before
    # the same loop under the realistic mode's former kernel (Cauchy, scale 1 on whitened residuals) is mostly
    # discounted: it removes less than half of the error between its frames
    cauchy = _graph(
        odom, [(target, source, measured)], CONFIG.model_copy(update={"loop_inliers": "all", "robust": "cauchy"})
    )
    assert _relative_error(cauchy.optimize(), gt, target, source) > 0.5 * before


@pytest.mark.parametrize("seed", range(5))
def test_a_wrong_loop_is_never_kept(drive, seed):
    """Wrong loops at random places, 20-80 m from the frame they claim (and turned by up to 10 deg), among two
    true loops: far more than the odometry between the loops can explain."""
    gt, odom = drive
    rng = np.random.default_rng(seed)
    loops = [_true(gt, 3), _true(gt, 14)]
    for _ in range(3):
        steps = int(rng.integers(0, REVISIT))
        offset = int(rng.integers(10, 41))
        offset = -offset if steps - offset >= 0 and rng.random() < 0.5 else offset
        target, source, measured = _wrong(gt, steps, offset)
        yaw = np.eye(4)
        yaw[:3, :3] = Rotation.from_euler("z", rng.uniform(-10, 10), degrees=True).as_matrix()
        loops.append((target, source, measured @ yaw))
    order = rng.permutation(len(loops))
    graph = _graph(odom, [loops[i] for i in order])
    optimised = graph.optimize()
    assert sorted(order[list(graph.inliers.kept)]) == [0, 1]
    np.testing.assert_allclose(optimised, _graph(odom, loops[:2]).optimize(), atol=1e-9)


def test_two_conflicting_loops_keep_the_one_odometry_finds_plausible(drive):
    """No partner to confirm either: the one whose correction the odometry covariance explains better stays."""
    gt, odom = drive
    graph = _graph(odom, [_wrong(gt, 10, 25), _true(gt, 10)])
    graph.optimize()
    assert graph.inliers.kept == (1,) and graph.inliers.consistent_pairs == 0


def test_consistency_follows_the_accumulated_odometry_covariance(drive):
    """Two true loops far apart are consistent; so are a wrong one and a true one when the odometry between
    them is too uncertain to tell, and not when it is certain."""
    gt, odom = drive
    path = PathCovariance()
    config = CONFIG
    for k, pose in enumerate(odom):
        path.append(pose, None if k == 0 else config.odometry_covariance(np.linalg.inv(odom[k - 1]) @ pose))
    a, b = (LoopEdge(t, s, m, LOOP_COV) for t, s, m in (_true(gt, 2), _true(gt, 18)))
    wrong = LoopEdge(*_wrong(gt, 3, 3), LOOP_COV)  # 6 m off, 2 m of odometry from loop a
    assert pair_chi2(a, b, path) < 1.0
    assert pair_chi2(a, wrong, path) > 50.0  # chi-square bound at 0.999: 22.5
    far_wrong = LoopEdge(*_wrong(gt, 18, 3), LOOP_COV)  # as wrong, but 32 m of odometry (sigma 1.1 m) from a
    assert pair_chi2(a, far_wrong, path) < 22.5  # the drift model's sigma over 32 m hides its 6 m error
    # the drift between the visits weighs on a single loop's test, not on the pair's
    assert single_chi2(a, path) > 10 * pair_chi2(a, b, path)
    loose = PathCovariance()
    for k, pose in enumerate(odom):
        step = np.linalg.inv(odom[k - 1]) @ pose if k else None
        loose.append(pose, None if k == 0 else 1e4 * config.odometry_covariance(step))
    assert pair_chi2(a, wrong, loose) < 1.0  # 100 times the sigma: a 6 m error is within the noise
    assert select_inliers([a, wrong, b], path, 0.999).kept == (0, 2)


def test_oracle_mode_uses_every_loop_and_realistic_mode_the_consistent_ones():
    from msa_slam.backend import IncrementalPoseGraph

    for graph in (PoseGraph, IncrementalPoseGraph):
        assert not graph(GraphConfig(), mode="oracle").selects_inliers
        assert graph(GraphConfig(), mode="realistic").selects_inliers
        assert graph(GraphConfig(), mode="realistic").kernel == "none"
        assert graph(GraphConfig(loop_inliers="all"), mode="realistic").kernel == "cauchy"


def _streamed(odom: np.ndarray, loops: list[tuple[int, int, np.ndarray]]):
    """iSAM2 given the loops as a run finds them (each when its newer keyframe arrives), updated every frame."""
    from msa_slam.backend import IncrementalPoseGraph

    arrivals = {loop[1]: loop for loop in loops}
    online = IncrementalPoseGraph(CONFIG, final_iterations=5, mode="realistic")
    used_after = {}
    for k, pose in enumerate(odom):
        online.add_keyframe(k, pose)
        if k in arrivals:
            online.add_loop(*arrivals[k])
        online.update(3 if k in arrivals else 0)
        if k in arrivals:
            used_after[k] = online.inliers.kept
    return online, used_after


def test_isam2_drops_a_wrong_loop_once_a_true_one_contradicts_it(drive):
    """A wrong loop that comes first is used while it is the only evidence (the estimate is then worse than
    odometry) and removed from iSAM2 when a true loop that contradicts it arrives (odometry finds the true one
    more plausible); the next true loop joins it. The end estimate is that of iSAM2 never given the wrong
    loop, and the batch graph keeps the same loops."""
    gt, odom = drive
    wrong, first, second = _wrong(gt, 2, 12), _true(gt, 6), _true(gt, 14)
    online, used_after = _streamed(odom, [wrong, first, second])
    assert used_after == {wrong[1]: (0,), first[1]: (1,), second[1]: (1, 2)}
    assert online.dropped_loops == (0,)
    assert online.factors.size() == len(odom) + 2
    clean, _ = _streamed(odom, [first, second])
    estimate = online.optimize()
    np.testing.assert_allclose(estimate, clean.optimize(), atol=1e-3)  # iSAM2's relinearisation history differs
    assert ate(estimate, gt).translation_rmse < 0.2 * ate(odom, gt).translation_rmse
    misled, _ = _streamed(odom, [wrong])
    assert ate(misled.optimize(), gt).translation_rmse > ate(odom, gt).translation_rmse
    batch = _graph(odom, [wrong, first, second])
    batch.optimize()
    assert batch.inliers.kept == online.inliers.kept


def _closer(length_m: float, **settings):
    """A LoopCloser over straight odometry of `length_m` in 1 m frames (only the drift check is used)."""
    from msa_slam.pipeline.config import make_config
    from msa_slam.slam import LoopCloser

    odometry = np.tile(np.eye(4), (int(length_m) + 1, 1, 1))
    odometry[:, 0, 3] = np.arange(len(odometry))
    closer = LoopCloser(None, None, make_config(dataset="unused", mode="realistic", **settings))
    closer._odometry = odometry
    return closer, len(odometry) - 1


def _lateral_loop(closer, query: int, metres: float):
    from msa_slam.types import LoopClosure

    T = np.linalg.inv(closer._odometry[0]) @ closer._odometry[query]
    T[1, 3] += metres  # the loop puts the query `metres` to the left of where odometry has it
    return LoopClosure(query, 0, 1.0, 0.0, travelled_m=float(query)), T


@pytest.mark.parametrize(
    "length_m, metres, accepted",
    [(100.0, 5.0, False), (1000.0, 5.0, True), (1000.0, 30.0, True), (1000.0, 120.0, False)],
)
def test_the_drift_gate_scales_with_the_accumulated_odometry_covariance(length_m, metres, accepted):
    """Sideways corrections with the default drift model, gate and slack: 5 m is beyond what 100 m of odometry
    can drift (sigma ~0.5 m); over 1,000 m the random walk's sigma is ~5.6 m (mostly the heading error's lever
    arm), 3.2 times that as systematic drift (~18 m), so 30 m passes (the random walk alone would refuse it:
    chi-square ~29) and 120 m does not."""
    closer, query = _closer(length_m)
    cand, T = _lateral_loop(closer, query, metres)
    assert closer.exceeds_drift(cand, T) is not accepted


def test_the_drift_gate_follows_the_configured_drift_model():
    """The same correction passes once the sequence's odometry is declared to drift 4 times as much."""
    closer, query = _closer(100.0)
    cand, T = _lateral_loop(closer, query, 4.0)
    assert closer.exceeds_drift(cand, T)
    loose, _ = _closer(
        100.0,
        graph={
            "drift_rotation": 4 * GraphConfig().drift_rotation,
            "drift_translation": 4 * GraphConfig().drift_translation,
        },
    )
    assert not loose.exceeds_drift(cand, T)


def test_beyond_the_search_budget_a_greedy_clique_is_kept(drive, monkeypatch):
    """The exact search stops after MAX_CLIQUE_CALLS calls; the greedy set it falls back to is still pairwise
    consistent and here the same as the exact one."""
    import msa_slam.backend.inliers as inliers

    gt, odom = drive
    loops = [_true(gt, 2), _wrong(gt, 5, 15), _true(gt, 12), _true(gt, 17), _wrong(gt, 8, 30)]
    exact = _graph(odom, loops)
    exact.optimize()
    monkeypatch.setattr(inliers, "MAX_CLIQUE_CALLS", 1)
    greedy = _graph(odom, loops)
    greedy.optimize()
    assert exact.inliers.method == "exact" and greedy.inliers.method == "greedy"
    assert greedy.inliers.kept == exact.inliers.kept == (0, 2, 3)


def test_the_slam_core_records_loops_left_out_as_inconsistent(drive):
    """Through the SLAM core: the loops the graph leaves out are the wrong ones, recorded as rejected for being
    inconsistent (not accepted, not counted as verified), and the g2o factors leave them out too."""
    from dataclasses import replace

    from msa_slam.descriptors import make_descriptor
    from msa_slam.pipeline.config import make_config
    from msa_slam.registration import KeyframeCloudStore
    from msa_slam.sampling import make_sampler
    from msa_slam.slam import KeyframeStore, SlamBackend
    from msa_slam.slam.loop_closing import loop_summary
    from msa_slam.types import LoopClosure

    gt, odom = drive
    planned = {
        source: (target, measured, wrong)
        for (target, source, measured), wrong in (
            (_true(gt, 2), False),
            (_wrong(gt, 5, 15), True),
            (_true(gt, 12), False),
        )
    }

    class Closer:  # loop closing as if these three loops were found and verified
        best_similarity: list[float] = []

        def candidates(self, frame, descriptor, gt_poses, odometry):
            if frame not in planned:
                return []
            target = planned[frame][0]
            distance = float(np.linalg.norm(gt_poses[frame, :3, 3] - gt_poses[target, :3, 3]))
            return [LoopClosure(frame, target, 0.9, distance, travelled_m=2.0 * (frame - target))]

        def verify(self, candidates):
            return [
                replace(c, verified=True, accepted=True, T_match_query=planned[c.query][1], covariance=LOOP_COV)
                for c in candidates
            ]

        def pr_curve(self):
            return None

    config = make_config(dataset="unused", sampler="all", mode="realistic")
    descriptor = make_descriptor("sc")
    cloud = np.random.default_rng(0).uniform(-20, 20, (200, 3))
    store = KeyframeStore(descriptor, KeyframeCloudStore(config.verifier.voxel_size))
    backend = SlamBackend(
        config,
        make_sampler("all"),
        store,
        Closer(),
        PoseGraph(config.graph, mode="realistic"),
        len(odom),
        "constructed",
    )
    desc = descriptor.compute(cloud)
    for i, pose in enumerate(odom):
        backend.add_frame(pose, desc, cloud, gt[i], 0.1 * i)
    result = backend.finish()
    assert [(c.query, c.accepted, c.rejected) for c in result.loops] == [
        (LAP + 2, True, ""),
        (LAP + 5, False, "inconsistent"),
        (LAP + 12, True, ""),
    ]
    summary = loop_summary(result.loops, config, result.graph_info)
    assert summary.rejected["inconsistent"] == 1 and summary.details["inlier_selection"]["kept"] == 2
    assert summary.details["loop_kernel"] == "none" and summary.details["loop_inliers"] == "consistent"
    assert result.graph_factors.size() == len(odom) + 2


def _random_loops(reach_m: float, count: int, seed: int = 0) -> list[np.ndarray]:
    """`count` transforms with any rotation (up to 180 deg) and translations up to `reach_m` long, half of them
    exactly that long (the bound's worst case)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(rng.normal(size=3) * rng.uniform(0, math.pi) / math.sqrt(3)).as_matrix()
        direction = rng.normal(size=3)
        T[:3, 3] = direction / np.linalg.norm(direction) * reach_m * (1.0 if k % 2 else rng.uniform())
        out.append(T)
    return out


def test_a_candidate_rejected_unregistered_has_no_loop_within_the_offset_that_passes_the_drift_check():
    """beyond_drift is a lower bound of the drift check's chi-square over every loop within the offset: where it
    says so, no such loop passes (rotations of any size, translations up to the offset in any direction)."""
    closer, query = _closer(100.0)
    cand, _ = _lateral_loop(closer, query, 0.0)  # odometry: the keyframes are 100 m apart
    assert closer.beyond_drift(cand, 30.0)
    assert all(closer.exceeds_drift(cand, T) for T in _random_loops(30.0, 400))
    assert not closer.beyond_drift(cand, 95.0)  # a loop 95 m long may agree with the odometry: register it


def test_a_candidate_whose_odometry_allows_a_loop_is_registered():
    """Keyframes the odometry puts 3 m apart after a 100 m drive: a loop near the odometry's passes the drift
    check, so the candidate is not rejected before registration."""
    closer, query = _closer(100.0)
    closer._odometry[query] = closer._odometry[3]
    cand, T = _lateral_loop(closer, query, 0.5)
    assert not closer.beyond_drift(cand, 30.0) and not closer.exceeds_drift(cand, T)


def _turned(T: np.ndarray, degrees: float) -> np.ndarray:
    """T with its rotation turned by `degrees` about the vertical."""
    out = T.copy()
    out[:3, :3] = out[:3, :3] @ Rotation.from_euler("z", degrees, degrees=True).as_matrix()
    return out


def test_a_candidate_whose_descriptor_yaw_the_heading_cannot_explain_has_no_loop_within_the_turn_that_passes():
    """Keyframes the odometry puts 3 m apart after 100 m, so the translation bound registers them; a descriptor yaw
    90 deg from the odometry's heading: every loop within MAX_LOOP_TURN_DEG of that yaw (and 30 m) fails the drift
    check, so beyond_drift rejects it. A yaw 10 deg off the heading is registered, and a loop near the odometry
    passes the drift check."""
    from msa_slam.slam.loop_closing import MAX_LOOP_TURN_DEG

    closer, query = _closer(100.0)
    closer._odometry[query] = closer._odometry[3]
    cand, T = _lateral_loop(closer, query, 0.5)
    guess = _turned(np.eye(4), 90.0)  # T_match_query from the descriptor: the odometry's heading turned by 90 deg
    assert closer.beyond_drift(cand, 30.0, guess, MAX_LOOP_TURN_DEG)
    turn = np.radians(MAX_LOOP_TURN_DEG)
    loops = _random_loops(30.0, 400)
    rng = np.random.default_rng(1)
    for L in loops:  # each loop's rotation within the turn of the guess, half of them exactly at it
        axis = rng.normal(size=3)
        angle = turn * (1.0 if rng.uniform() < 0.5 else rng.uniform())
        L[:3, :3] = guess[:3, :3] @ Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
    assert all(closer.exceeds_drift(cand, L) for L in loops)
    near = _turned(np.eye(4), 10.0)
    assert not closer.beyond_drift(cand, 30.0, near, MAX_LOOP_TURN_DEG) and not closer.exceeds_drift(cand, T)


@pytest.mark.parametrize("dof", [1, 3, 6])
def test_chi2_quantile_is_scipys_to_the_bit(dof):
    """The gates' chi-square bounds, computed without importing scipy.stats, are its chi2.ppf exactly."""
    for confidence in (1e-6, 0.05, 0.5, 0.9, 0.95, 0.99, 0.999, 0.9999, 1 - 1e-9):
        assert chi2_quantile(confidence, dof) == float(chi2.ppf(confidence, dof))
    with pytest.raises(InputError, match="0 < confidence < 1"):
        chi2_quantile(1.0, dof)


def _brute_force_clique(neighbours: list[set[int]], score: np.ndarray) -> set[int]:
    """The largest pairwise-connected subset, ties to the lower score sum, then to the lower sorted indices."""
    from itertools import combinations

    n = len(neighbours)
    for size in range(n, 0, -1):
        cliques = [c for c in combinations(range(n), size) if all(b in neighbours[a] for a, b in combinations(c, 2))]
        if cliques:
            return set(min(cliques, key=lambda c: (float(score[list(c)].sum()), sorted(c))))
    return set()


@pytest.mark.parametrize("seed", range(6))
def test_the_exact_clique_is_the_largest_and_most_plausible_set(seed):
    """On random consistency graphs (ties in size included) the exact search keeps what an exhaustive search
    over every subset keeps."""
    from msa_slam.backend.inliers import _maximum_clique

    rng = np.random.default_rng(seed)
    n = 11
    edges = np.triu(rng.random((n, n)) < 0.6, 1)
    neighbours = [set(np.flatnonzero(edges[i] | edges[:, i]).tolist()) for i in range(n)]
    score = rng.integers(0, 3, n).astype(float)  # integer scores: equal sums happen, so the index rule decides
    clique, method = _maximum_clique(neighbours, score)
    assert method == "exact"
    assert clique == _brute_force_clique(neighbours, score)


def test_a_clique_deeper_than_the_recursion_limit_is_found_exactly():
    """A revisit driven through twice gives hundreds of mutually consistent loops: the search does not recurse
    once per loop (which stopped a KITTI-00 run at Python's recursion limit), so a clique far deeper than the
    limit in force is found, and exactly."""
    import inspect
    import sys

    from msa_slam.backend.inliers import _maximum_clique

    n = 400
    neighbours = [set(range(n)) - {i} for i in range(n)]
    neighbours[7] -= {11}  # one inconsistent pair: a maximum clique leaves one of them out
    neighbours[11] -= {7}
    score = np.ones(n)
    score[11] = 0.5  # loop 11 is the more plausible one
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(len(inspect.stack()) + 100)
    try:
        clique, method = _maximum_clique(neighbours, score)
    finally:
        sys.setrecursionlimit(limit)
    assert method == "exact"
    assert clique == set(range(n)) - {7}
