"""GTSAM pose graphs on a constructed drifting loop: a loop factor reduces ATE; LM and iSAM2 agree; odometry
edges weighted by a drift model give a chain whose stiffness does not depend on how it is split; loop
covariances stay within bounds; the robust kernel follows the verification mode and loop selection."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msa_slam.backend import GraphConfig, IncrementalPoseGraph, PoseGraph
from msa_slam.backend.keyframe_graph import FACTOR_BYTES
from msa_slam.backend.noise import bounded_covariance
from msa_slam.errors import InputError
from msa_slam.evaluation import ate


def _square(steps_per_side: int = 5, step: float = 2.0) -> np.ndarray:
    """Ground truth: a closed square driven in `step` m moves, turning left at each corner; ends at start."""
    poses, pose = [], np.eye(4)
    move = np.eye(4)
    move[0, 3] = step
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    for leg in range(4):
        for _ in range(steps_per_side):
            poses.append(pose.copy())
            pose = pose @ move
        pose = pose @ turn
    poses.append(pose.copy())
    return np.stack(poses)


# The drift model of the constructed odometry below: 3 % of the distance and 1.5 deg per 2 m step.
SQUARE = GraphConfig(drift_translation=0.03, drift_rotation=math.radians(0.75))


def _drift(gt: np.ndarray) -> np.ndarray:
    """Odometry: every true step with +1.5 deg yaw and +3 % length, so the loop does not close."""
    bias = np.eye(4)
    bias[:3, :3] = Rotation.from_euler("z", 1.5, degrees=True).as_matrix()
    odom = [gt[0]]
    for a, b in zip(gt[:-1], gt[1:]):
        step = np.linalg.inv(a) @ b
        step[:3, 3] *= 1.03
        odom.append(odom[-1] @ step @ bias)
    return np.stack(odom)


def _build(graph, odom: np.ndarray, gt: np.ndarray, loop: bool) -> None:
    for k, pose in enumerate(odom):
        graph.add_keyframe(k, pose)
    if loop:  # the last pose revisits the first: measured from ground truth, as a verified loop would be
        graph.add_loop(0, len(gt) - 1, np.linalg.inv(gt[0]) @ gt[-1])


@pytest.fixture(scope="module")
def square():
    gt = _square()
    return gt, _drift(gt)


def test_loop_factor_reduces_ate(square):
    gt, odom = square
    without = PoseGraph(SQUARE)
    _build(without, odom, gt, loop=False)
    with_loop = PoseGraph(SQUARE)
    _build(with_loop, odom, gt, loop=True)
    before = ate(odom, gt).translation_rmse
    np.testing.assert_allclose(without.optimize(), odom, atol=1e-6)  # odometry alone is already optimal
    after = ate(with_loop.optimize(), gt)
    assert before > 0.5
    assert after.translation_rmse < 0.4 * before
    assert ate(with_loop.optimize(), gt).rotation_rmse < ate(odom, gt).rotation_rmse
    assert with_loop.num_loops == 1 and with_loop.num_factors == len(gt) + 1


def test_isam2_agrees_with_levenberg_marquardt(square):
    gt, odom = square
    batch, online = PoseGraph(SQUARE), IncrementalPoseGraph(SQUARE)
    _build(batch, odom, gt, loop=True)
    for k, pose in enumerate(odom):  # online: keyframes arrive one update at a time, then the loop
        online.add_keyframe(k, pose)
        online.update()
    np.testing.assert_allclose(online.estimate(), odom, atol=1e-6)
    online.add_loop(0, len(gt) - 1, np.linalg.inv(gt[0]) @ gt[-1])
    np.testing.assert_allclose(online.optimize(), batch.optimize(), atol=1e-3)
    assert online.nbytes > batch.nbytes > 0


def test_robust_kernel_limits_a_wrong_loop(square):
    gt, odom = square
    wrong = np.eye(4)
    wrong[:3, 3] = [30.0, -20.0, 0.0]  # a false loop 36 m off
    plain, robust = PoseGraph(SQUARE), PoseGraph(SQUARE.model_copy(update={"robust": "cauchy"}))
    for graph in (plain, robust):
        _build(graph, odom, gt, loop=True)
        graph.add_loop(5, len(gt) - 3, wrong)
    assert ate(robust.optimize(), gt).translation_rmse < 0.5 * ate(plain.optimize(), gt).translation_rmse


def test_memory_accounting_grows_with_factors(square):
    gt, odom = square
    graph = PoseGraph()
    graph.add_keyframe(0, odom[0])
    one = graph.nbytes
    graph.add_keyframe(1, odom[1])
    assert graph.nbytes == 2 * one and len(graph) == 2 and graph.keys == [0, 1]
    np.testing.assert_array_equal(graph.initial_poses(), odom[:2])


@pytest.mark.parametrize("make", [PoseGraph, IncrementalPoseGraph])
def test_bad_input_raises(make, square):
    _, odom = square
    graph = make()
    with pytest.raises(InputError, match="no keyframes"):
        graph.optimize()
    graph.add_keyframe(0, odom[0])
    graph.add_keyframe(1, odom[1])
    with pytest.raises(InputError, match="keyframe 7 is not in the pose graph"):
        graph.add_loop(0, 7, np.eye(4))
    with pytest.raises(InputError, match="already added"):
        graph.add_keyframe(1, odom[1])
    nan_pose = odom[2].copy()
    nan_pose[0, 3] = np.nan
    with pytest.raises(InputError, match="keyframe 2 pose"):
        graph.add_keyframe(2, nan_pose)
    with pytest.raises(InputError, match="loop 0->1 transform"):
        graph.add_loop(0, 1, np.full((4, 4), np.nan))
    with pytest.raises(InputError, match="two different"):
        graph.add_loop(1, 1, np.eye(4))
    with pytest.raises(InputError, match="non-negative integer"):
        graph.add_keyframe(-3, odom[2])
    assert graph.num_factors == 2 and len(graph) == 2


def test_bad_noise_raises():
    with pytest.raises(InputError, match="graph: robust: Input should be"):
        GraphConfig(robust="tukey-ish")
    with pytest.raises(InputError, match="odometry_translation"):
        GraphConfig(odometry_translation=-1.0)


def test_isam2_accounting_counts_loop_fill_in(square):
    gt, odom = square
    chain, looped = IncrementalPoseGraph(), IncrementalPoseGraph()
    _build(chain, odom, gt, loop=False)
    _build(looped, odom, gt, loop=True)
    chain.update()
    looped.update()
    # one more factor alone adds FACTOR_BYTES; the loop's fill-in of the Bayes tree adds far more
    assert looped.nbytes - chain.nbytes > 10 * FACTOR_BYTES


def test_batch_graph_is_independent_of_the_order_loops_arrive_in():
    """Streaming keyframes and loops as they are found (the SLAM core) optimises bit for bit as adding every
    keyframe first: loop factors always follow the odometry chain (interleaved factors differ by ~1e-14)."""
    gt = _square(50, 0.5)
    odom = _drift(gt)
    pairs = np.random.default_rng(0).integers(0, len(gt), (80, 2))
    loops = sorted({(int(a), int(b)) for a, b in pairs if b - a > 5}, key=lambda pair: pair[1])
    config = GraphConfig(robust="cauchy")
    first = PoseGraph(config)
    for k, pose in enumerate(odom):
        first.add_keyframe(k, pose)
    for a, b in loops:
        first.add_loop(a, b, np.linalg.inv(gt[a]) @ gt[b])
    streamed = PoseGraph(config)
    for k, pose in enumerate(odom):
        streamed.add_keyframe(k, pose)
        for a, b in loops:
            if b == k:
                streamed.add_loop(a, b, np.linalg.inv(gt[a]) @ gt[b])
        streamed.update()  # nothing happens before optimize()
    np.testing.assert_array_equal(streamed.optimize(), first.optimize())


def _arc(length: float, edges: int) -> np.ndarray:
    """Poses along one constant-twist motion (a climbing left turn of 60 deg over `length` m), in `edges` edges."""
    xi = np.array([0.01, 0.02, math.radians(60), length, 0.0, 0.5])  # GTSAM order: rotation, translation
    return np.stack([gtsam.Pose3.Expmap(xi * k / edges).matrix() for k in range(edges + 1)])


def _end_covariance(poses: np.ndarray, config: GraphConfig | None = None) -> np.ndarray:
    graph = PoseGraph(config)
    for k, pose in enumerate(poses):
        graph.add_keyframe(k, pose)
    factors, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    factors.push_back(graph._graph)
    values.insert(graph._values)
    return gtsam.Marginals(factors, values).marginalCovariance(len(poses) - 1)


def test_chain_covariance_does_not_depend_on_the_number_of_edges():
    """The drift model's covariance over a stretch is the same whether 2 or 20 keyframes split it (the
    per-edge floor, 1e-4 m and 1e-5 rad, is the only difference), and it grows with the distance."""
    two, twenty = _end_covariance(_arc(40.0, 2)), _end_covariance(_arc(40.0, 20))
    np.testing.assert_allclose(twenty, two, rtol=2e-3, atol=1e-9)
    longer = _end_covariance(_arc(80.0, 2))
    assert np.all(np.diag(longer)[3:] > 1.9 * np.diag(two)[3:])
    fixed = GraphConfig(odometry_noise="fixed")  # the old fixed sigma per edge: 20 edges are far looser
    assert _end_covariance(_arc(40.0, 20), fixed)[3, 3] > 5 * _end_covariance(_arc(40.0, 2), fixed)[3, 3]


def test_edge_covariance_matches_the_calibration():
    """Over the reference length the translation sigma along the path is the stated relative drift."""
    config = GraphConfig()
    straight = np.eye(4)
    straight[0, 3] = config.drift_reference_m
    cov = config.drift.edge_covariance(straight)
    assert math.sqrt(cov[3, 3]) == pytest.approx(config.drift_translation * config.drift_reference_m)
    assert math.sqrt(cov[5, 5]) > math.sqrt(cov[3, 3])  # pitch drift adds a vertical lever arm


def test_loop_covariance_is_kept_within_bounds():
    lo, hi = np.repeat([0.004, 0.05], 3), np.repeat([0.09, 1.0], 3)
    overconfident = bounded_covariance(np.diag(np.repeat([1e-8, 1e-6], 3)), lo, hi)
    np.testing.assert_allclose(np.sqrt(np.diag(overconfident)), lo)
    degenerate = np.diag([1e-6] * 5 + [1e12])  # a corridor: one direction unconstrained
    capped = bounded_covariance(degenerate, lo, hi)
    np.testing.assert_allclose(np.sqrt(np.diag(capped)), [*lo[:5], hi[5]])
    middle = np.diag(np.repeat([0.01, 0.2], 3) ** 2)
    np.testing.assert_allclose(bounded_covariance(middle, lo, hi), middle)


def test_loop_covariance_weights_the_loop(square):
    """A loop registered with large uncertainty corrects the drift less than a precise one."""
    gt, odom = square
    errors = []
    for sigma in (0.05, 1.0):
        graph = PoseGraph(SQUARE)
        for k, pose in enumerate(odom):
            graph.add_keyframe(k, pose)
        covariance = np.diag(np.repeat([sigma / 10, sigma], 3) ** 2)
        graph.add_loop(0, len(gt) - 1, np.linalg.inv(gt[0]) @ gt[-1], covariance)
        errors.append(ate(graph.optimize(), gt).translation_rmse)
    assert errors[0] < errors[1]
    with pytest.raises(InputError, match="covariance must be a finite 6x6"):
        graph.add_loop(0, 3, np.eye(4), np.eye(3))


def test_robust_kernel_follows_the_mode():
    """ "auto": none in oracle mode and where the batch graph keeps only consistent loops (realistic mode);
    Cauchy in realistic mode when every loop is used (iSAM2, or loop_inliers=all)."""
    assert PoseGraph(mode="realistic").kernel == "none" and PoseGraph(mode="oracle").kernel == "none"
    assert PoseGraph(GraphConfig(loop_inliers="all"), mode="realistic").kernel == "cauchy"
    assert IncrementalPoseGraph(mode="realistic").kernel == "none"
    assert IncrementalPoseGraph(GraphConfig(loop_inliers="all"), mode="realistic").kernel == "cauchy"
    assert PoseGraph(GraphConfig(robust="huber"), mode="oracle").kernel == "huber"
