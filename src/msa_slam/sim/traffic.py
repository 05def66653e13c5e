"""Where traffic may drive and walk without touching the ego vehicle: the path as arc lengths, the ego's place on
it at any time, and the parts of the street that a lane or a walk may use.

The model (right-hand traffic, as KITTI's Germany; with `WorldRealism.right_hand_traffic` the city style's
two-way street is driven in its right lane: parked cars' centres 3.3-4.3 m to the right, the left row one lane
farther out, 6.3-7.3 m, `layout.Style.left_shift`; the plain world's street is symmetric about the path):

- Same direction: the ego's own lane carries one car ahead of it and one behind, each at a distance from the
  ego that varies smoothly with the ego's own progress along the path (between a following distance and beyond
  the range the dynamic objects are cast to), so they keep their distance when the ego stops and never drive
  backwards (`following_gap`). No car overtakes: the street has no second lane in the ego's direction.
- Oncoming: a lane `Style.oncoming_lane` m to the left. Oncoming cars drive only where the lane is free: no
  parked car (static or coming-and-going), wall or pole on it, and no stretch of the ego's path (where the path
  comes back, the ego itself drives there), in runs long enough not to flicker (`Road.lane_free`). On a two-way
  street that is most of it; on the plain world's symmetric street (4.7-7 m between the rows of parked cars, room
  for the ego only) only where it has no parking.
- Pedestrians walk beside the path (sidewalks); a walk that would reach the ego's road anywhere (where the
  path crosses or comes back) is left out (`Road.clear_of_ego`).

Clearances are between oriented footprints: the ego's (`Style.ego_half` about the sensor, along the path's heading
at each of its positions) and each object's, by footprints.rect_gaps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msa_slam.sim.footprints import Footprints, PathClearance, rect_gaps

CLEARANCE = 0.25  # m: the least gap a moving object keeps from the ego's footprint wherever the ego drives
FOLLOW_NEAR = (10.0, 20.0)  # m, sensor to car centre: the closest a car ahead or behind comes (a following distance)
FOLLOW_FAR = 150.0  # m: the farthest it drops back, beyond the dynamic objects' cast radius
FOLLOW_WAVE = (600.0, 1500.0)  # m of the ego's path per cycle of that distance: slow enough never to reverse
LANE_STEP = 1.0  # m: the oncoming lane is checked at every LANE_STEP of arc length
MIN_LANE_RUN = 30.0  # m: shorter free stretches of the oncoming lane carry no car (it would pop in and out)
MIN_TURN_RADIUS = 5.0  # m: the tightest curve a car drives (a kerb-to-kerb turning circle of about 10-11 m)


@dataclass
class PathFrame:
    """Arc-length parametrisation of the (extended) path: point and heading at any arc length."""

    xy: np.ndarray
    arc: np.ndarray

    @classmethod
    def of(cls, xy: np.ndarray) -> PathFrame:
        return cls(xy, np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]))

    @property
    def length(self) -> float:
        return float(self.arc[-1])

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points (K, 2) and unit headings (K, 2) at arc lengths `s` (K,)."""

        def interp(v: np.ndarray) -> np.ndarray:
            return np.column_stack([np.interp(v, self.arc, self.xy[:, 0]), np.interp(v, self.arc, self.xy[:, 1])])

        h = interp(s + 2.0) - interp(s - 2.0)
        return interp(s), h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-9)


@dataclass
class EgoClock:
    """The ego's arc length on the extended path at its poses' times (s, the clock `World.cast` is given)."""

    times: np.ndarray
    arc: np.ndarray

    def arc_at(self, time: float) -> float:
        """Arc length at `time`, interpolated between poses (held before the first and after the last)."""
        return float(np.interp(time, self.times, self.arc))


def following_gap(ego_arc: float, near: np.ndarray, wave: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """Distance (m) of each same-direction car from the ego when the ego is at `ego_arc`: from `near` out to
    FOLLOW_FAR and back over every `wave` m the ego drives. Its rate against the ego's progress stays below 1
    (FOLLOW_WAVE against FOLLOW_FAR - FOLLOW_NEAR), so the car moves the ego's way whenever the ego moves and
    stands when it stands."""
    return near + (FOLLOW_FAR - near) * 0.5 * (1.0 - np.cos(2.0 * np.pi * (ego_arc + phase) / wave))


class Road:
    """What moving objects may use: footprints clear of the ego's at every path position and of placed
    structure (see the module docstring)."""

    def __init__(self, path: PathFrame, ego_half: tuple[float, float], clear: PathClearance, taken: Footprints) -> None:
        self.path = path
        self.ego_half = np.asarray(ego_half, dtype=np.float64)
        self.clear = clear
        self.taken = taken
        _, heading = path.at(clear.arc)  # PathClearance densifies the same path: its arc lengths are the path's
        self._ego_yaw = np.arctan2(heading[:, 1], heading[:, 0])

    def clear_of_ego(self, xy: np.ndarray, half: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """(K,) bool: which footprints (centres (K, 2), half extents (K, 2), yaws (K,)) keep CLEARANCE from the
        ego's footprint at every point of its path."""
        reach = float(np.hypot(*self.ego_half)) + np.hypot(half[:, 0], half[:, 1]) + CLEARANCE + 0.5
        out = np.ones(len(xy), dtype=bool)
        for k, near in enumerate(self.clear.tree.query_ball_point(xy, reach)):
            if near:
                idx = np.asarray(near)
                gaps = rect_gaps(self.clear.points[idx], self.ego_half, self._ego_yaw[idx], xy[k], half[k], yaw[k])
                out[k] = bool(gaps.min() >= CLEARANCE + 0.25)  # path points are 0.5 m apart: the ego drives between
        return out

    def lane_free(self, lateral: float, half: tuple[float, float]) -> np.ndarray:
        """Bool per LANE_STEP of arc length: whether a car (`half` extents) centred there on the lane `lateral` m
        to the left of the path fits (clear of the ego's path and of placed structure) and can drive it (where the
        ego turns left the lane, on the inside, turns on a radius `lateral` m tighter: not under MIN_TURN_RADIUS),
        kept only in free runs of at least MIN_LANE_RUN m."""
        s = np.arange(0.0, self.path.length + LANE_STEP, LANE_STEP)
        p, h = self.path.at(s)
        xy = p + np.column_stack([-h[:, 1], h[:, 0]]) * lateral
        yaw = np.arctan2(h[:, 1], h[:, 0])
        halves = np.tile(np.asarray(half, dtype=np.float64), (len(s), 1))
        left_turn = np.gradient(np.unwrap(yaw), s) if len(s) > 1 else np.zeros(len(s))  # rad per m
        free = left_turn * (lateral + MIN_TURN_RADIUS) <= 1.0
        free &= self.clear_of_ego(xy, halves, yaw)
        free &= np.array([f and self.taken.is_free(c, halves[0], a, 0.3) for f, c, a in zip(free, xy, yaw)])
        edges = np.flatnonzero(np.diff(np.concatenate([[0], free.astype(np.int8), [0]])))
        for start, end in zip(edges[::2], edges[1::2]):
            if (end - start) * LANE_STEP < MIN_LANE_RUN:
                free[start:end] = False
        return free
