"""Simulated traffic against the ego vehicle: what the scans see of moving objects never comes within a clearance
of the ego car, and oncoming cars pass on the left (right-hand traffic, as KITTI's)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from msa_slam.errors import InputError
from msa_slam.sim.config import SimConfig
from msa_slam.sim.dynamic import DRIVE, FOLLOW
from msa_slam.sim.footprints import rect_gaps
from msa_slam.sim.simulation import Simulation, prepare
from msa_slam.sim.world import WorldRealism, build_world

EGO_HALF = np.array([2.5, 1.0])  # KITTI's estate car (4.8 x 1.8 m) about the roof's sensor, rounded up
CLEARANCE = 0.5  # m between the ego's footprint and any box cast against it


@cache
def _sim(trajectory: str, end: int | None = None) -> Simulation:
    return prepare(SimConfig(trajectory=trajectory, end=end, realism="kitti", seed=0, azimuth_steps=180))


def _ego_at(sim: Simulation, k: int) -> tuple[float, np.ndarray, float]:
    """Time, sensor position and heading of frame k in the frame the world was built in."""
    level = np.eye(3) if sim.world.levelling is None else sim.world.levelling
    pose = sim.poses[k]
    forward = level @ pose[:3, 0]
    return float(sim.trajectory.times[sim.frames[k]]), level @ pose[:3, 3], float(np.arctan2(forward[1], forward[0]))


def test_rect_gaps_never_exceed_the_distance_between_the_rectangles():
    rng = np.random.default_rng(0)
    n = 400
    a_c, b_c = rng.uniform(-6, 6, (n, 2)), rng.uniform(-6, 6, (n, 2))
    a_h, b_h = rng.uniform(0.2, 2.5, (n, 2)), rng.uniform(0.2, 2.5, (n, 2))
    a_y, b_y = rng.uniform(-np.pi, np.pi, n), rng.uniform(-np.pi, np.pi, n)
    gaps = rect_gaps(a_c, a_h, a_y, b_c, b_h, b_y)
    u = np.linspace(-1.0, 1.0, 11)
    grid = np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)
    for k in range(n):
        pts = []
        for c, h, y in ((a_c[k], a_h[k], a_y[k]), (b_c[k], b_h[k], b_y[k])):
            rot = np.array([[np.cos(y), -np.sin(y)], [np.sin(y), np.cos(y)]])
            pts.append(c + (grid * h) @ rot.T)
        dist = np.min(np.linalg.norm(pts[0][:, None] - pts[1][None], axis=2))  # sampled: >= the true distance
        assert gaps[k] <= dist + 1e-9
        if dist > 1.0:  # apart (the grid samples each rectangle to within 0.35 m): the bound is positive
            assert gaps[k] > 0
    aligned = rect_gaps(np.zeros(2), np.array([2.5, 1.0]), 0.0, np.array([[0.0, 3.0]]), np.array([2.4, 0.95]), 0.0)
    assert aligned == pytest.approx([1.05])


@pytest.mark.parametrize(("trajectory", "end"), [("kitti-07", 400), ("reverse-revisit", None)])
def test_no_box_cast_comes_near_the_ego_vehicle(trajectory: str, end: int | None):
    """At every frame's time, every dynamic box the scan is cast against (moving cars, pedestrians, transient
    parked cars) keeps CLEARANCE from the ego's footprint EGO_HALF about the sensor, turned to its heading:
    KITTI-07's start (a standstill at a junction, residential streets) and a revisit driven the other way in the
    other lane."""
    sim = _sim(trajectory, end)
    cast = 0
    for k in range(len(sim)):
        time, position, heading = _ego_at(sim, k)
        centres, half, yaw, _, _ = sim.world.dynamic.boxes_at(time, position[None], 120.0)
        gaps = rect_gaps(position[:2], EGO_HALF, heading, centres[:, :2], half[:, :2], yaw)
        assert np.all(gaps >= CLEARANCE), f"frame {k}: a box {gaps.min():.2f} m from the ego's footprint"
        cast += len(centres)
    assert cast > 10 * len(sim)  # the scans do see traffic


def _straight(sim: Simulation, time: float, span: float = 15.0, tolerance_deg: float = 10.0) -> bool:
    """Whether the path runs straight within `span` m of where the ego is at `time` (no junction turn)."""
    dyn = sim.world.dynamic
    _, h = dyn.path.at(dyn.ego.arc_at(time) + np.array([-span, 0.0, span]))
    turn = np.degrees(np.diff(np.unwrap(np.arctan2(h[:, 1], h[:, 0]))))
    return bool(np.all(np.abs(turn) < tolerance_deg))


def test_oncoming_cars_pass_a_lane_to_the_left_and_cars_ahead_keep_their_distance():
    """Right-hand traffic: where the street runs straight, an oncoming car abreast of the ego is on its left, a lane
    over (its centre at least the two cars' half widths plus CLEARANCE to the side), heading the other way (in a
    junction, turning or crossing, "abreast" in the ego's frame is no lane: the clearance test above covers those);
    a car in the ego's lane goes its way, ahead or behind it."""
    sim = _sim("kitti-07")
    dyn = sim.world.dynamic
    passed = followed = 0
    for k in range(0, len(sim), 2):
        time, position, heading = _ego_at(sim, k)
        pos, yaw = dyn.poses_at(time)
        rel = pos[:, :2] - position[:2]
        along = rel @ np.array([np.cos(heading), np.sin(heading)])
        left = rel @ np.array([-np.sin(heading), np.cos(heading)])
        facing = np.cos(yaw - heading)
        near = dyn.present(time) & (np.abs(along) < 5.0) & (np.abs(left) < 8.0) & (dyn.motion == DRIVE)
        beside = np.abs(np.mod(dyn.s0 + dyn.speed * time, dyn.path.length) - dyn.ego.arc_at(time)) < 15.0
        near &= beside & _straight(sim, time)  # on the ego's own street, not one crossing it at a junction
        assert np.all(left[near] >= EGO_HALF[1] + 0.95 + CLEARANCE) and np.all(facing[near] < -0.5)
        passed += int(near.any())
        lane = dyn.present(time) & (dyn.motion == FOLLOW) & (np.abs(along) < 25.0) & (np.abs(left) < 3.0)
        assert np.all(facing[lane] > 0.7) and np.all(np.abs(along[lane]) >= 2 * EGO_HALF[0] + CLEARANCE)
        followed += int(lane.any())
    assert passed >= 30 and followed >= 20  # frames with an oncoming car abreast (46 of 551), a car ahead or behind


def test_the_world_refuses_times_that_do_not_match_its_poses():
    poses = np.tile(np.eye(4), (50, 1, 1))
    poses[:, 0, 3] = np.arange(50.0)
    with pytest.raises(InputError, match="49 times for 50 poses"):
        build_world(poses, "city", realism=WorldRealism(moving_cars=1.0), times=np.arange(49) / 10.0)
