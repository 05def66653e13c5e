"""Things that move or come and go: moving cars and pedestrians on their own trajectories along the path,
and parked cars that are present only in some time windows (so revisits of a place differ).

Each object is rigid and made of at most two boxes in its own frame. `DynamicObjects.cast` places the
objects near the rays at a time, builds a tiny mesh of them and casts against it with Embree: the static
world is never rebuilt, and a scan stays fast. Positions and presence are pure functions of the time and
of values drawn once per world, so any frame can be simulated on its own, deterministically.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from trimesh.ray.ray_pyembree import RayMeshIntersector

from msa_slam.sim.shapes import Material, MeshBuilder

FIXED, DRIVE, WALK = 0, 1, 2  # motion kinds: in place (maybe transient), along the path, back and forth
_NEAR = 1.0  # objects whose footprint comes this close to a ray origin are dropped (they would hold the sensor)


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
class DynamicObjects:
    """K rigid objects: parts (K, 2, 6) local box centres and half extents (a zero box is no part),
    reflectance, material and motion per object; see the module docstring."""

    path: PathFrame
    ground: Callable[[np.ndarray], np.ndarray]
    seed: int
    parts: np.ndarray
    refl: np.ndarray
    material: np.ndarray
    motion: np.ndarray
    s0: np.ndarray  # DRIVE/WALK: arc length at time 0
    speed: np.ndarray  # DRIVE: signed m/s along the path; WALK: m/s
    lateral: np.ndarray  # DRIVE/WALK: offset along the path's left normal
    span: np.ndarray  # WALK: length of the stretch walked back and forth
    xy: np.ndarray  # FIXED: position (K, 2)
    z: np.ndarray  # FIXED: ground height
    yaw: np.ndarray  # FIXED: heading
    period: np.ndarray  # presence epochs (s); 0 = always present
    keep: np.ndarray  # probability of being present in an epoch

    def __len__(self) -> int:
        return len(self.motion)

    def present(self, time: float) -> np.ndarray:
        """(K,) bool: which objects exist at `time` (each transient one flips a seeded coin per epoch)."""
        out = np.ones(len(self), dtype=bool)
        tr = self.period > 0
        if tr.any():
            ids = np.flatnonzero(tr)
            epochs = np.floor(time / self.period[tr] + unit_hash(ids, np.zeros_like(ids), self.seed)).astype(np.int64)
            out[tr] = unit_hash(ids, epochs, self.seed + 1) < self.keep[tr]
        return out

    def poses_at(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """Positions (K, 3) on the ground and headings (K,) at `time`."""
        pos = np.column_stack([self.xy, self.z])
        yaw = self.yaw.copy()
        moving = self.motion != FIXED
        if moving.any():
            total = self.path.length
            s = self.s0[moving] + self.speed[moving] * time
            walk = self.motion[moving] == WALK
            span = self.span[moving][walk]
            u = np.mod(self.speed[moving][walk] * time / span + self.s0[moving][walk] / total, 2.0)
            s = np.mod(s, total)  # drivers go round (a car leaving one end stands for one entering the other)
            s[walk] = self.s0[moving][walk] + span * np.minimum(u, 2.0 - u)  # back and forth
            p, h = self.path.at(s)
            normal = np.column_stack([-h[:, 1], h[:, 0]])
            xy = p + normal * self.lateral[moving, None]
            pos[moving, :2] = xy
            pos[moving, 2] = self.ground(xy)
            back = np.where(self.speed[moving] < 0, np.pi, 0.0)
            yaw[moving] = np.arctan2(h[:, 1], h[:, 0]) + back
        return pos, yaw

    def boxes_at(self, time: float, origins: np.ndarray, radius: float) -> tuple[np.ndarray, ...]:
        """World boxes (centres, half extents, yaw, reflectance, material) of the objects present at `time`
        within `radius` of the ray `origins` (M, 3) and not on top of one of them."""
        pos, yaw = self.poses_at(time)
        foot = np.hypot(self.parts[:, :, 3].max(1), self.parts[:, :, 4].max(1))
        d = np.linalg.norm(pos[:, None, :2] - origins[None, :, :2], axis=2)
        keep = self.present(time) & (d.min(1) < radius) & (d.min(1) > foot + _NEAR)
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
        tri, sub = RayMeshIntersector(mesh).intersects_id(origins[cand], directions[cand], multiple_hits=False)
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
    """How many objects to make: moving cars and pedestrians per 100 m of path, and the transient
    parked cars (fixed poses) the layout chose; presence epochs of `period` seconds."""

    cars_per_100m: float
    pedestrians_per_100m: float
    car_lanes: tuple[float, float]  # lateral offsets: with the path's direction, against it
    pedestrian_offset: tuple[float, float]
    period: float


def _car_parts(rng: np.random.Generator, n: int) -> np.ndarray:
    """Body and cabin boxes of `n` cars (as the layout's parked cars), relative to the ground point."""
    hl, hw, cab = rng.uniform(1.9, 2.4, n), rng.uniform(0.8, 0.95, n), rng.uniform(1.3, 1.5, n)
    parts = np.zeros((n, 2, 6))
    parts[:, 0, 2:] = np.column_stack([np.full(n, 0.6), hl, hw, np.full(n, 0.45)])
    parts[:, 1, 2:] = np.column_stack([1.05 + cab * 0.25, hl * 0.55, hw * 0.9, cab * 0.25])
    return parts


def make_dynamic(
    path: PathFrame,
    ground: Callable[[np.ndarray], np.ndarray],
    recipe: DynamicRecipe,
    parked: np.ndarray,
    rng: np.random.Generator,
    seed: int,
) -> DynamicObjects | None:
    """Moving cars, pedestrians and the transient parked cars `parked` (P, 11: x, y, z, yaw, body half
    length and width, cabin centre height and half extents, reflectance); None when there are none."""
    total = path.length
    n_car = int(round(recipe.cars_per_100m * total / 100.0))
    n_ped = int(round(recipe.pedestrians_per_100m * total / 100.0))
    n_fix = len(parked)
    k = n_car + n_ped + n_fix
    if k == 0:
        return None
    parts = np.zeros((k, 2, 6))
    refl = np.zeros(k)
    material = np.full(k, Material.VEHICLE, dtype=np.uint8)
    motion = np.full(k, FIXED)
    s0, speed, lateral, span = np.zeros(k), np.zeros(k), np.zeros(k), np.ones(k)
    xy, z, yaw = np.zeros((k, 2)), np.zeros(k), np.zeros(k)
    period, keep = np.zeros(k), np.ones(k)

    cars = slice(0, n_car)
    parts[cars] = _car_parts(rng, n_car)
    refl[cars] = rng.uniform(0.3, 0.9, n_car)
    motion[cars] = DRIVE
    s0[cars] = rng.uniform(0.0, total, n_car)
    forward = rng.random(n_car) < 0.5
    speed[cars] = np.where(forward, 1.0, -1.0) * rng.uniform(5.0, 14.0, n_car)
    lateral[cars] = np.where(forward, recipe.car_lanes[0], recipe.car_lanes[1])

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
    lateral[peds] = np.where(rng.random(n_ped) < 0.5, 1.0, -1.0) * rng.uniform(*recipe.pedestrian_offset, n_ped)

    fix = slice(n_car + n_ped, k)
    if n_fix:
        xy[fix], z[fix], yaw[fix] = parked[:, :2], parked[:, 2], parked[:, 3]
        parts[fix, 0, 2:] = np.column_stack([np.full(n_fix, 0.6), parked[:, 4:6], np.full(n_fix, 0.45)])
        parts[fix, 1, 2:] = parked[:, 6:10]
        refl[fix] = parked[:, 10]
        period[fix] = recipe.period
        keep[fix] = 0.5
    return DynamicObjects(
        path, ground, seed, parts, refl, material, motion, s0, speed, lateral, span, xy, z, yaw, period, keep
    )
