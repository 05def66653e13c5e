"""Things that move or come and go: moving cars and pedestrians on their own trajectories along the path,
and parked cars that are present only in some time windows (so revisits of a place differ).

Each object is rigid and made of at most two boxes in its own frame. `DynamicObjects.cast` places the
objects near the rays at a time, builds a tiny mesh of them and casts against it with Embree: the static
world is never rebuilt, and a scan stays fast. Positions and presence are pure functions of the time and
of values drawn once per world, so any frame can be simulated on its own, deterministically. Where traffic
drives and walks, so that it never touches the ego vehicle, is `traffic`'s model.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from msa_slam.sim.footprints import rect_gaps
from msa_slam.sim.raycast import FirstHits
from msa_slam.sim.shapes import Material, MeshBuilder
from msa_slam.sim.traffic import (
    CLEARANCE,
    FOLLOW_NEAR,
    FOLLOW_WAVE,
    LANE_STEP,
    EgoClock,
    PathFrame,
    Road,
    following_gap,
)

# motion kinds: in place (maybe transient), oncoming along the path, back and forth, ahead of or behind the ego
FIXED, DRIVE, WALK, FOLLOW = 0, 1, 2, 3
_NEAR = 1.0  # objects whose footprint comes this close to a ray origin are dropped (they would hold the sensor)
CAR_HALF = (2.4, 0.95)  # the largest car's half length and width (_car_parts)
ONCOMING_SPEED = (8.0, 14.0)  # m/s: one speed for the whole oncoming lane, so no car drives through another
ONCOMING_SPACING = 10.0  # m: the least distance between oncoming cars' centres


def unit_hash(ids: np.ndarray, epochs: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic uniform [0, 1) values per (id, epoch) pair (splitmix64): presence is decided
    for any time without storing a schedule."""
    with np.errstate(over="ignore"):
        x = (
            np.asarray(ids, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
            + np.asarray(epochs, dtype=np.int64).astype(np.uint64) * np.uint64(0xBF58476D1CE4E5B9)
            + np.uint64(seed & 0xFFFFFFFF) * np.uint64(0x94D049BB133111EB)
        )
        x ^= x >> np.uint64(30)
        x *= np.uint64(0xBF58476D1CE4E5B9)
        x ^= x >> np.uint64(27)
        x *= np.uint64(0x94D049BB133111EB)
        x ^= x >> np.uint64(31)
    return (x >> np.uint64(11)).astype(np.float64) / float(1 << 53)


@dataclass
class DynamicObjects:
    """K rigid objects: parts (K, 2, 6) local box centres and half extents (a zero box is no part),
    reflectance, material and motion per object; see the module docstring."""

    path: PathFrame
    ground: Callable[[np.ndarray], np.ndarray]
    seed: int
    ego: EgoClock  # where the ego is on the path at any time: FOLLOW cars keep their distance from it
    ego_half: np.ndarray  # (2,) the ego's footprint about the sensor (half length, half width)
    lane: np.ndarray  # DRIVE: whether the oncoming lane is free, per LANE_STEP of arc length (traffic.Road)
    parts: np.ndarray
    refl: np.ndarray
    material: np.ndarray
    motion: np.ndarray
    s0: np.ndarray  # DRIVE/WALK: arc length at time 0; FOLLOW: phase (m) of its distance's cycle
    speed: np.ndarray  # DRIVE: signed m/s along the path; WALK: m/s; FOLLOW: +1 ahead of the ego, -1 behind
    lateral: np.ndarray  # DRIVE/WALK/FOLLOW: offset along the path's left normal
    span: np.ndarray  # WALK: length of the stretch walked back and forth; FOLLOW: m of ego path per distance cycle
    near: np.ndarray  # FOLLOW: its closest distance to the ego (m)
    xy: np.ndarray  # FIXED: position (K, 2)
    z: np.ndarray  # FIXED: ground height
    yaw: np.ndarray  # FIXED: heading
    period: np.ndarray  # presence epochs (s); 0 = always present
    keep: np.ndarray  # probability of being present in an epoch

    def __len__(self) -> int:
        return len(self.motion)

    def _arc_at(self, time: float) -> np.ndarray:
        """(K,) arc lengths of the moving objects at `time` (0 for FIXED ones); a FOLLOW car's may fall off
        the path's ends."""
        s = np.zeros(len(self))
        drive, walk, follow = (self.motion == kind for kind in (DRIVE, WALK, FOLLOW))
        total = self.path.length
        # oncoming cars go round (one leaving one end stands for one entering the other)
        s[drive] = np.mod(self.s0[drive] + self.speed[drive] * time, total)
        u = np.mod(self.speed[walk] * time / self.span[walk] + self.s0[walk] / total, 2.0)
        s[walk] = self.s0[walk] + self.span[walk] * np.minimum(u, 2.0 - u)  # back and forth
        ego = self.ego.arc_at(time)
        s[follow] = ego + self.speed[follow] * following_gap(ego, self.near[follow], self.span[follow], self.s0[follow])
        return s

    def present(self, time: float) -> np.ndarray:
        """(K,) bool: which objects exist at `time`: each transient one flips a seeded coin per epoch, an
        oncoming car drives only where its lane is free, a car ahead or behind only on the path."""
        out = np.ones(len(self), dtype=bool)
        tr = self.period > 0
        if tr.any():
            ids = np.flatnonzero(tr)
            epochs = np.floor(time / self.period[tr] + unit_hash(ids, np.zeros_like(ids), self.seed)).astype(np.int64)
            out[tr] = unit_hash(ids, epochs, self.seed + 1) < self.keep[tr]
        s = self._arc_at(time)
        drive, follow = self.motion == DRIVE, self.motion == FOLLOW
        cell = np.minimum(np.round(s[drive] / LANE_STEP).astype(np.int64), len(self.lane) - 1)
        out[drive] &= self.lane[cell]
        out[follow] &= (s[follow] >= 0.0) & (s[follow] <= self.path.length) & self._clear_of_ego(time, follow)
        return out

    def _clear_of_ego(self, time: float, which: np.ndarray) -> np.ndarray:
        """Whether the objects `which` keep CLEARANCE from the ego's footprint at `time`: a car ahead of or behind
        the ego along the path may stand beside it where the path comes back within its distance."""
        p, h = self.path.at(np.array([self.ego.arc_at(time)]))
        pos, yaw = self.poses_at(time)
        half = self.footprint_half()
        gaps = rect_gaps(p[0], self.ego_half, np.arctan2(h[0, 1], h[0, 0]), pos[which, :2], half[which], yaw[which])
        return gaps >= CLEARANCE

    def poses_at(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """Positions (K, 3) on the ground and headings (K,) at `time`."""
        pos = np.column_stack([self.xy, self.z])
        yaw = self.yaw.copy()
        moving = self.motion != FIXED
        if moving.any():
            p, h = self.path.at(self._arc_at(time)[moving])
            xy = p + np.column_stack([-h[:, 1], h[:, 0]]) * self.lateral[moving, None]
            pos[moving, :2] = xy
            pos[moving, 2] = self.ground(xy)
            back = np.where((self.motion[moving] == DRIVE) & (self.speed[moving] < 0), np.pi, 0.0)  # oncoming
            yaw[moving] = np.arctan2(h[:, 1], h[:, 0]) + back
        return pos, yaw

    def footprint_half(self) -> np.ndarray:
        """(K, 2) half length and width of each object's footprint, in its own frame."""
        return np.abs(self.parts[:, :, :2]).max(1) + self.parts[:, :, 3:5].max(1)

    def boxes_at(self, time: float, origins: np.ndarray, radius: float) -> tuple[np.ndarray, ...]:
        """World boxes (centres, half extents, yaw, reflectance, material) of the objects present at `time`
        within `radius` of the ray `origins` (M, 3) and whose footprint stays _NEAR from every origin (the
        traffic model keeps moving objects off the ego's path; this is the guard for rays cast elsewhere)."""
        pos, yaw = self.poses_at(time)
        rel = origins[None, :, :2] - pos[:, None, :2]
        c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        half = self.footprint_half()
        dx = np.maximum(np.abs(c * rel[..., 0] + s * rel[..., 1]) - half[:, :1], 0.0)
        dy = np.maximum(np.abs(-s * rel[..., 0] + c * rel[..., 1]) - half[:, 1:], 0.0)
        gap = np.hypot(dx, dy).min(1)
        d = np.linalg.norm(rel, axis=2).min(1)
        keep = self.present(time) & (d < radius) & (gap > _NEAR)
        idx = np.flatnonzero(keep)
        parts = self.parts[idx]
        valid = parts[:, :, 3] > 0
        k, p = np.nonzero(valid)
        c, s = np.cos(yaw[idx][k]), np.sin(yaw[idx][k])
        local = parts[k, p]
        centres = pos[idx][k] + np.column_stack(
            [c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1], local[:, 2]]
        )
        return centres, local[:, 3:6], yaw[idx][k], self.refl[idx][k], self.material[idx][k]

    def cast(
        self, origins: np.ndarray, directions: np.ndarray, time: float, radius: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """First hits on the objects at `time`: ray index, distance, unit normal, reflectance, material."""
        sample = origins[:: max(1, len(origins) // 64)]
        centres, half, yaw, refl, material = self.boxes_at(time, sample, radius)
        if len(centres) == 0:
            return (
                np.zeros(0, np.int64),
                np.zeros(0),
                np.zeros((0, 3)),
                np.zeros(0, np.float32),
                np.zeros(0, np.uint8),
            )
        builder = MeshBuilder()
        builder.boxes(centres, half, yaw, refl, material)
        mesh, face_refl, face_material = builder.build()
        cand = _candidate_rays(origins, directions, centres, np.linalg.norm(half, axis=1))
        tri, sub = FirstHits(mesh).cast(origins[cand], directions[cand])
        ray = cand[sub]
        normals = np.asarray(mesh.face_normals)[tri]
        corner = np.asarray(mesh.triangles[:, 0, :])[tri]
        dist = np.einsum("ij,ij->i", corner - origins[ray], normals) / np.einsum("ij,ij->i", directions[ray], normals)
        return ray, dist, normals, face_refl[tri], face_material[tri]


_AZ_BINS, _EL_BINS = 720, 180  # a 0.5 x 1 degree grid of directions


def _candidate_rays(origins: np.ndarray, directions: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Indices of the rays whose direction falls in the angular footprint of some box (its bounding
    sphere seen from the origins' centre, widened by the origins' spread): casting only those keeps the
    dynamic cast a small fraction of the static one."""
    centre = origins.mean(0) if origins.strides[0] else origins[0]
    spread = float(np.linalg.norm(origins - centre, axis=1).max()) if origins.strides[0] else 0.0
    rel = centres - centre
    dist = np.linalg.norm(rel, axis=1)
    grid = np.zeros((_EL_BINS, _AZ_BINS), dtype=bool)
    reach = radii + spread + 0.1
    near = dist <= reach * 1.05
    if near.any():
        return np.arange(len(directions))
    half = np.arcsin(reach / dist)
    az = np.arctan2(rel[:, 1], rel[:, 0])
    el = np.arcsin(np.clip(rel[:, 2] / dist, -1.0, 1.0))
    for a, e, w in zip(az, el, half):
        e0 = int(np.floor((e - w + np.pi / 2) / np.pi * _EL_BINS))
        e1 = int(np.floor((e + w + np.pi / 2) / np.pi * _EL_BINS))
        cols = (
            np.arange(
                int(np.floor((a - w + np.pi) / (2 * np.pi) * _AZ_BINS)),
                int(np.floor((a + w + np.pi) / (2 * np.pi) * _AZ_BINS)) + 1,
            )
            % _AZ_BINS
        )
        grid[max(e0, 0) : min(e1, _EL_BINS - 1) + 1, cols] = True
    ray_az = ((np.arctan2(directions[:, 1], directions[:, 0]) + np.pi) / (2 * np.pi) * _AZ_BINS).astype(np.int64)
    ray_el = ((np.arcsin(np.clip(directions[:, 2], -1.0, 1.0)) + np.pi / 2) / np.pi * _EL_BINS).astype(np.int64)
    return np.flatnonzero(grid[np.minimum(ray_el, _EL_BINS - 1), ray_az % _AZ_BINS])


@dataclass
class DynamicRecipe:
    """How many objects to make: oncoming cars per 100 m of their lane (and with them one car ahead of the ego and
    one behind it), pedestrians per 100 m of path, and the transient parked cars (fixed poses) the layout
    chose; presence epochs of `period` seconds. Where they go: `traffic`."""

    cars_per_100m: float
    pedestrians_per_100m: float
    oncoming_lane: float  # m: the oncoming lane's centre to the left of the path
    pedestrian_offset: tuple[float, float]
    period: float
    left_shift: float = 0.0  # m: how much farther out the left footpath is (layout.Style.left_shift)


def _car_parts(rng: np.random.Generator, n: int) -> np.ndarray:
    """Body and cabin boxes of `n` cars (as the layout's parked cars), relative to the ground point."""
    hl, hw, cab = rng.uniform(1.9, CAR_HALF[0], n), rng.uniform(0.8, CAR_HALF[1], n), rng.uniform(1.3, 1.5, n)
    parts = np.zeros((n, 2, 6))
    parts[:, 0, 2:] = np.column_stack([np.full(n, 0.6), hl, hw, np.full(n, 0.45)])
    parts[:, 1, 2:] = np.column_stack([1.05 + cab * 0.25, hl * 0.55, hw * 0.9, cab * 0.25])
    return parts


def _oncoming_starts(rng: np.random.Generator, per_100m: float, total: float) -> np.ndarray:
    """Arc lengths at time 0 of the oncoming cars: gaps of 0.5-1.5 times the mean spacing, at least
    ONCOMING_SPACING, also across the ends (where the lane's cars go round)."""
    if per_100m <= 0:
        return np.zeros(0)
    gaps = np.maximum(rng.uniform(0.5, 1.5, int(total / ONCOMING_SPACING) + 1) * 100.0 / per_100m, ONCOMING_SPACING)
    starts = np.cumsum(gaps)
    return starts[starts < total - ONCOMING_SPACING]


def _walks_clear(road: Road, lateral: np.ndarray, s0: np.ndarray, span: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(N,) bool: which walks (offset `lateral`, arc lengths s0..s0 + span, footprint `half` (N, 2)) keep clear
    of the ego wherever its path goes (a walk beside one street may cross another)."""
    ok = np.ones(len(s0), dtype=bool)
    for k in range(len(s0)):
        s = np.append(np.arange(s0[k], s0[k] + span[k], 1.0), s0[k] + span[k])
        p, h = road.path.at(s)
        xy = p + np.column_stack([-h[:, 1], h[:, 0]]) * lateral[k]
        ok[k] = bool(road.clear_of_ego(xy, np.tile(half[k], (len(s), 1)), np.arctan2(h[:, 1], h[:, 0])).all())
    return ok


def make_dynamic(
    path: PathFrame,
    ground: Callable[[np.ndarray], np.ndarray],
    recipe: DynamicRecipe,
    parked: np.ndarray,
    road: Road,
    ego: EgoClock,
    rng: np.random.Generator,
    seed: int,
) -> DynamicObjects | None:
    """Cars in the oncoming lane and one ahead of and one behind the ego (with any cars at all), pedestrians
    whose walks keep clear of the ego, and the transient parked cars `parked` (P, 11: x, y, z, yaw, body half
    length and width, cabin centre height and half extents, reflectance); None when there are none."""
    total = path.length
    oncoming = _oncoming_starts(rng, recipe.cars_per_100m, total)
    n_on = len(oncoming)
    n_follow = 2 if recipe.cars_per_100m > 0 else 0
    n_car = n_on + n_follow
    n_ped = int(round(recipe.pedestrians_per_100m * total / 100.0))
    n_fix = len(parked)
    k = n_car + n_ped + n_fix
    if k == 0:
        return None
    parts = np.zeros((k, 2, 6))
    refl = np.zeros(k)
    material = np.full(k, Material.VEHICLE, dtype=np.uint8)
    motion = np.full(k, FIXED)
    s0, speed, lateral, span, near = np.zeros(k), np.zeros(k), np.zeros(k), np.ones(k), np.zeros(k)
    xy, z, yaw = np.zeros((k, 2)), np.zeros(k), np.zeros(k)
    period, keep = np.zeros(k), np.ones(k)

    cars = slice(0, n_car)
    parts[cars] = _car_parts(rng, n_car)
    refl[cars] = rng.uniform(0.3, 0.9, n_car)
    on = slice(0, n_on)
    motion[on] = DRIVE
    s0[on] = oncoming
    speed[on] = -rng.uniform(*ONCOMING_SPEED)
    lateral[on] = recipe.oncoming_lane
    follow = slice(n_on, n_car)
    motion[follow] = FOLLOW
    speed[follow] = (1.0, -1.0)[:n_follow]  # one ahead, one behind
    near[follow] = rng.uniform(*FOLLOW_NEAR, n_follow)
    span[follow] = rng.uniform(*FOLLOW_WAVE, n_follow)
    s0[follow] = rng.uniform(0.0, 1.0, n_follow) * span[follow]
    lane = road.lane_free(recipe.oncoming_lane, CAR_HALF) if n_on else np.zeros(1, dtype=bool)

    peds = slice(n_car, n_car + n_ped)
    half_height = rng.uniform(0.78, 0.95, n_ped)
    parts[peds, 0, 2:] = np.column_stack(
        [half_height, rng.uniform(0.2, 0.3, n_ped), rng.uniform(0.15, 0.22, n_ped), half_height]
    )
    refl[peds] = rng.uniform(0.15, 0.6, n_ped)
    material[peds] = Material.PERSON
    motion[peds] = WALK
    span[peds] = np.minimum(rng.uniform(15.0, 60.0, n_ped), total)
    s0[peds] = rng.uniform(0.0, 1.0, n_ped) * (total - span[peds])  # the walk stays on the path
    speed[peds] = rng.uniform(0.8, 1.8, n_ped)
    left = rng.random(n_ped) < 0.5
    lateral[peds] = np.where(left, 1.0, -1.0) * rng.uniform(*recipe.pedestrian_offset, n_ped) + left * recipe.left_shift
    rows = np.ones(k, dtype=bool)
    rows[peds] = _walks_clear(road, lateral[peds], s0[peds], span[peds], parts[peds, 0, 3:5])

    fix = slice(n_car + n_ped, k)
    if n_fix:
        xy[fix], z[fix], yaw[fix] = parked[:, :2], parked[:, 2], parked[:, 3]
        parts[fix, 0, 2:] = np.column_stack([np.full(n_fix, 0.6), parked[:, 4:6], np.full(n_fix, 0.45)])
        parts[fix, 1, 2:] = parked[:, 6:10]
        refl[fix] = parked[:, 10]
        period[fix] = recipe.period
        keep[fix] = 0.5
    per_object = (parts, refl, material, motion, s0, speed, lateral, span, near, xy, z, yaw, period, keep)
    return DynamicObjects(path, ground, seed, ego, road.ego_half, lane, *(a[rows] for a in per_object))
