"""Streets laid out for right-hand traffic (the `kitti` presets): the path is the right lane's centre of a two-way
street, so everything on its left stands a lane farther out, the oncoming lane is free where the street has one,
and no static object stands in the ego's lane on any pass where the path comes back beside itself."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from msa_slam.sim import world as world_module
from msa_slam.sim.config import SimConfig
from msa_slam.sim.dynamic import DRIVE
from msa_slam.sim.layout import STYLES, StreetLayout
from msa_slam.sim.realism import REALISM
from msa_slam.sim.shapes import Material
from msa_slam.sim.simulation import prepare
from msa_slam.sim.traffic import PathFrame, Road
from msa_slam.sim.trajectories import load_trajectory


def _inner_offsets(layout: StreetLayout) -> tuple[np.ndarray, np.ndarray]:
    """Signed lateral centre (+: left) and the distance of the nearest edge from the path of every footprint
    placed along a straight path on the x axis."""
    centre = np.array([r[0] for r in layout.taken.rects])
    half = np.array([r[1] for r in layout.taken.rects])
    yaw = np.array([r[2] for r in layout.taken.rects])
    reach = np.abs(np.sin(yaw)) * half[:, 0] + np.abs(np.cos(yaw)) * half[:, 1]
    return centre[:, 1], np.abs(centre[:, 1]) - reach


@pytest.mark.parametrize("seed", [0, 1])
def test_the_left_side_of_a_straight_city_street_stands_a_lane_farther_out(seed: int):
    """On a straight city street the nearest footprints on the left (parked cars, poles, trees, walls, blocks) are
    at least a lane (Style.oncoming_lane) farther from the path than those on the right, the parked cars' centres
    within the style's offsets on the right and a lane beyond them on the left; the plain world keeps the street
    symmetric."""
    xy = np.column_stack([np.arange(0.0, 600.0), np.zeros(600)])
    gaps = {}
    for two_way in (False, True):
        style = replace(STYLES["city"], two_way=two_way)
        layout = StreetLayout(xy, style, np.random.default_rng(seed), lambda p: 0.0)
        layout.build()
        lateral, inner = _inner_offsets(layout)
        left, right = lateral > 0, lateral < 0
        assert left.sum() > 40 and right.sum() > 40
        gaps[two_way] = [np.percentile(inner[left], q) - np.percentile(inner[right], q) for q in (0, 5, 10)]
        cars = np.array(
            [b[:2] for b in layout.boxes if b[8] == Material.VEHICLE and b[2] < 1.0]
        )  # bodies (cabins sit higher)
        on_left = cars[:, 1] > 0
        lo, hi = style.car_offset
        assert np.all((cars[~on_left, 1] <= -lo + 1e-9) & (cars[~on_left, 1] >= -hi - 1e-9))
        shift = style.oncoming_lane if two_way else 0.0
        assert np.all((cars[on_left, 1] >= lo + shift - 1e-9) & (cars[on_left, 1] <= hi + shift + 1e-9))
    assert all(g >= STYLES["city"].oncoming_lane - 0.2 for g in gaps[True]), gaps[True]
    assert all(abs(g) < 1.0 for g in gaps[False]), gaps[False]


def test_campus_walkways_stay_symmetric():
    assert STYLES["campus"].left_shift == 0.0 and STYLES["city"].left_shift == STYLES["city"].oncoming_lane
    assert REALISM["kitti"].world.right_hand_traffic and REALISM["kitti-hard"].world.right_hand_traffic
    assert not REALISM["clean"].world.right_hand_traffic


def test_oncoming_cars_drive_beside_kitti_07s_parked_cars():
    """KITTI-07's first 400 frames run through residential streets lined with parked cars on both sides: with the
    left row a lane out, the oncoming lane is free on most of them (92 % of the path, seed 0) and an oncoming car
    is within 50 m of the sensor in at least 80 % of the frames (390 of 400; none when the street was symmetric)."""
    sim = prepare(SimConfig(trajectory="kitti-07", end=400, realism="kitti", seed=0, azimuth_steps=180))
    dyn = sim.world.dynamic
    assert dyn.lane.mean() > 0.8
    level = np.eye(3) if sim.world.levelling is None else sim.world.levelling
    frames = 0
    for k in range(len(sim)):
        time = float(sim.trajectory.times[sim.frames[k]])
        position = level @ sim.poses[k][:3, 3]
        centres, _ = dyn.poses_at(time)
        near = np.linalg.norm(centres[:, :2] - position[:2], axis=1) < 50.0
        frames += bool(np.any(dyn.present(time) & (dyn.motion == DRIVE) & near))
    assert frames >= 0.8 * len(sim)


def test_no_static_footprint_in_the_ego_lane_on_either_pass_of_a_reverse_revisit(monkeypatch):
    """`reverse-revisit` comes back down its street in the other lane, 2.5 m to the side: every static footprint
    (blocks, walls, trees, poles, parked cars, transient cars' slots) keeps out of the ego's lane (half of
    Style.oncoming_lane to each side of the path: the ego's half width plus traffic.Road's clearance) at every
    point of both passes, and the street does have a left row a lane farther out."""
    built: list[StreetLayout] = []

    class Recorded(StreetLayout):
        def build(self) -> None:
            super().build()
            built.append(self)

    monkeypatch.setattr(world_module, "StreetLayout", Recorded)
    poses = load_trajectory("reverse-revisit").poses
    world_module.build_world(poses, "city", seed=0, realism=REALISM["kitti"].world)
    layout = built[0]
    style = layout.style
    assert style.left_shift == style.oncoming_lane
    road = Road(PathFrame.of(layout.xy), style.ego_half, layout.clear, layout.taken)
    assert style.ego_half[1] + 0.5 == pytest.approx(style.oncoming_lane / 2)  # what clear_of_ego keeps clear
    centre = np.array([r[0] for r in layout.taken.rects])
    half = np.array([r[1] for r in layout.taken.rects])
    yaw = np.array([r[2] for r in layout.taken.rects])
    clear = road.clear_of_ego(centre, half, yaw)
    assert len(clear) > 100 and clear.all(), f"{(~clear).sum()} footprints in the ego's lane"
