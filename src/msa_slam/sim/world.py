"""A simulated world: one static triangle mesh around a trajectory plus optional dynamic objects, with
Embree ray casting.

The ground follows the trajectory (sensor height below each pose, so slopes and bridges of real paths
are respected) with mild relief away from the road; street structure comes from `layout`, its plan of
reused designs and hard stretches from `plan`, moving and transient objects from `dynamic`.
`WorldRealism` holds every knob; its defaults are off and reproduce the plain world byte for byte.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from msa_slam.errors import InputError
from msa_slam.sim.dynamic import DynamicObjects, DynamicRecipe, make_dynamic, unit_hash
from msa_slam.sim.layout import STYLES, StreetLayout
from msa_slam.sim.level import LEVEL_DEG, gravity_up, levelling_rotation, tilt_deg
from msa_slam.sim.plan import HARD_KINDS, Stretch, first_visits, make_catalogue, plan_stretches
from msa_slam.sim.raycast import FirstHits
from msa_slam.sim.shapes import Material, MeshBuilder
from msa_slam.sim.traffic import EgoClock, PathFrame, Road

PATH_LEAD = 80.0  # m of straight street laid before the first pose and after the last
START_STRUCTURE_M = 60.0  # no hard stretch over the lead and the first metres: odometry must pick up the motion
DYNAMIC_RADIUS = 120.0  # dynamic objects farther than this from the rays' origins are not cast against


@dataclass(frozen=True)
class WorldRealism:
    """World knobs; every default is "off". Densities per 100 m of path, shares of path length."""

    moving_cars: float = 0.0  # oncoming cars per 100 m of their lane; with any, one car ahead of the ego, one behind
    pedestrians: float = 0.0  # people walking back and forth beside the path
    transient_parking: float = 0.0  # share of parking slots whose car comes and goes
    parked_occupancy: float = 0.0  # share of car slots with a parked car on streets that have parking (0: the style's)
    turnover_period: float = 60.0  # s: a transient car is there or not per epoch of this length
    catalogue_designs: int = 0  # street designs reused in different places (perceptual aliasing)
    km_per_design: float = 0.0  # more designs on longer paths: one per this many km of first visits (0: off)
    catalogue_share: float = 0.0  # share of the path laid out from the catalogue
    design_variants: int = 1  # house types per design, laid in an irregular order (1: identical houses)
    hard_share: float = 0.0  # share of the path in stretches where ICP degenerates along the path
    hard_kinds: tuple[str, ...] = HARD_KINDS
    foliage_gap: float = 0.0  # share of rays that pass a crown's surface, drawn per scan and ray
    upright: bool = False  # build along gravity (level.gravity_up), not along the trajectory frame's z
    right_hand_traffic: bool = False  # two-way streets driven in their right lane (layout.Style.left_shift)

    def __post_init__(self) -> None:
        for name in ("moving_cars", "pedestrians"):
            if not 0.0 <= getattr(self, name) <= 20.0:
                raise InputError(f"world realism: {name} must be in [0, 20] per 100 m, got {getattr(self, name)}")
        for name in ("transient_parking", "parked_occupancy", "catalogue_share", "hard_share", "foliage_gap"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise InputError(f"world realism: {name} must be in [0, 1), got {getattr(self, name)}")
        if self.catalogue_share + self.hard_share > 0.9:
            raise InputError(
                f"world realism: catalogue_share + hard_share must be <= 0.9, got "
                f"{self.catalogue_share} + {self.hard_share}"
            )
        if not self.turnover_period > 0:
            raise InputError(f"world realism: turnover_period must be > 0 s, got {self.turnover_period}")
        if self.catalogue_designs < 0 or (self.catalogue_share > 0 and self.catalogue_designs < 1):
            raise InputError(
                f"world realism: catalogue_designs must be >= 1 when catalogue_share > 0, got {self.catalogue_designs}"
            )
        if not 0.0 <= self.km_per_design <= 100.0:
            raise InputError(f"world realism: km_per_design must be in [0, 100], got {self.km_per_design}")
        if not 1 <= self.design_variants <= 8:
            raise InputError(f"world realism: design_variants must be in [1, 8], got {self.design_variants}")
        unknown = sorted(set(self.hard_kinds) - set(HARD_KINDS))
        if unknown or (self.hard_share > 0 and not self.hard_kinds):
            raise InputError(
                f"world realism: hard_kinds {list(self.hard_kinds)} must be a non-empty subset of "
                f"{', '.join(HARD_KINDS)}"
            )

    def designs_for(self, first_visit_m: float) -> int:
        """How many designs a path with `first_visit_m` m of first visits gets: at least `catalogue_designs`, and
        one per `km_per_design` km, so that each design comes back about as often on a long drive as on a short
        one (with two designs KITTI-00's 3.1 km had each design's streets four to five times, and look-alikes
        outscored a third of its true revisits)."""
        if self.km_per_design <= 0:
            return self.catalogue_designs
        return max(self.catalogue_designs, round(first_visit_m / (1000.0 * self.km_per_design)))

    @classmethod
    def clean(cls) -> WorldRealism:
        """Everything off: the plain world."""
        return cls()


@dataclass(frozen=True)
class Hits:
    """First hits of a cast, one row per ray that hit: static face (-1 on a dynamic object), ray index,
    distance, unit face normal, reflectance and `Material` code. Unpacks as (tri, ray, dist), the
    values `World.cast` returned before dynamic objects existed."""

    tri: np.ndarray
    ray: np.ndarray
    dist: np.ndarray
    normal: np.ndarray
    reflectance: np.ndarray
    material: np.ndarray

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter((self.tri, self.ray, self.dist))

    def __len__(self) -> int:
        return len(self.ray)


class World:
    """A static mesh with per-face reflectance and material, and optional dynamic objects; `cast` gives
    the first hit of each ray at a time. Arc lengths in `stretches` start `PATH_LEAD` m before the first pose.
    An upright world is built in a levelled frame: `levelling` (3, 3) takes the trajectory's frame, in which
    rays are given, to it (None: the same frame)."""

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        reflectance: np.ndarray,
        material: np.ndarray | None = None,
        dynamic: DynamicObjects | None = None,
        realism: WorldRealism = WorldRealism(),
        seed: int = 0,
        stretches: tuple[Stretch, ...] = (),
        levelling: np.ndarray | None = None,
    ) -> None:
        self.mesh = mesh
        self.reflectance = reflectance
        self.material = (
            np.full(len(mesh.faces), Material.SOLID, dtype=np.uint8)
            if material is None
            else np.asarray(material, dtype=np.uint8)
        )
        self.dynamic = dynamic
        self.realism = realism
        self.seed = seed
        self.stretches = stretches  # the planned designed and hard stretches, arc lengths on the extended path
        self.levelling = levelling
        self.face_normals = np.asarray(mesh.face_normals)
        self._face_origins = np.asarray(mesh.triangles[:, 0, :])
        self._first_hits = FirstHits(mesh)

    @property
    def triangles(self) -> int:
        """Triangles of the static mesh."""
        return len(self.mesh.faces)

    def _cast_static(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The distance comes from the hit triangle's plane, cheaper than asking trimesh for hit locations."""
        tri, ray = self._first_hits.cast(origins, directions)
        normals = self.face_normals[tri]
        num = np.einsum("ij,ij->i", self._face_origins[tri] - origins[ray], normals)
        dist = num / np.einsum("ij,ij->i", directions[ray], normals)
        return tri, ray, dist

    def cast(self, origins: np.ndarray, directions: np.ndarray, time: float = 0.0) -> Hits:
        """First hits of unit `directions` (R, 3) from `origins` ((3,) or (R, 3)) against the static mesh
        and the dynamic objects as they are at `time` (s on the trajectory's clock); normals in the rays' frame."""
        origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), directions.shape)
        if self.levelling is not None:
            hits = self._cast_level(origins @ self.levelling.T, directions @ self.levelling.T, time)
            return replace(hits, normal=hits.normal @ self.levelling)
        return self._cast_level(origins, directions, time)

    def _cast_level(self, origins: np.ndarray, directions: np.ndarray, time: float) -> Hits:
        """`cast` in the frame the world was built in."""
        tri, ray, dist = self._cast_static(origins, directions)
        if self.realism.foliage_gap > 0:
            tri, ray, dist = self._through_foliage(origins, directions, tri, ray, dist, time)
        hits = Hits(tri, ray, dist, self.face_normals[tri], self.reflectance[tri], self.material[tri])
        if self.dynamic is not None:
            hits = self._with_dynamic(self.dynamic, hits, origins, directions, time)
        return hits

    def _through_foliage(
        self,
        origins: np.ndarray,
        directions: np.ndarray,
        tri: np.ndarray,
        ray: np.ndarray,
        dist: np.ndarray,
        time: float,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A seeded share of the rays that hit a crown pass its surface (a gap in the leaves, different at
        every scan) and return from what lies behind: the crown's far side or beyond."""
        veg = np.flatnonzero(self.material[tri] == Material.VEGETATION)
        epoch = np.full(len(veg), int(round(time * 1000.0)))
        veg = veg[unit_hash(ray[veg], epoch, self.seed + 7) < self.realism.foliage_gap]
        if len(veg) == 0:
            return tri, ray, dist
        rays = ray[veg]
        start = origins[rays] + directions[rays] * (dist[veg, None] + 0.05)
        tri2, sub, dist2 = self._cast_static(start, directions[rays])
        keep = np.ones(len(ray), dtype=bool)
        keep[veg] = False
        tri = np.concatenate([tri[keep], tri2])
        ray_all = np.concatenate([ray[keep], rays[sub]])
        dist = np.concatenate([dist[keep], dist[veg][sub] + 0.05 + dist2])
        order = np.argsort(ray_all, kind="stable")
        return tri[order], ray_all[order], dist[order]

    def _with_dynamic(
        self, dynamic: DynamicObjects, hits: Hits, origins: np.ndarray, directions: np.ndarray, time: float
    ) -> Hits:
        """Static hits replaced by nearer hits on the dynamic objects (and rays that only hit those);
        rows stay in ray order."""
        ray_d, dist_d, normal_d, refl_d, mat_d = dynamic.cast(origins, directions, time, DYNAMIC_RADIUS)
        pos = np.minimum(np.searchsorted(hits.ray, ray_d), max(len(hits.ray) - 1, 0))
        has_static = (hits.ray[pos] == ray_d) if len(hits.ray) else np.zeros(len(ray_d), dtype=bool)
        swap = has_static & (dist_d < hits.dist[pos] if len(hits.ray) else has_static)
        new = ~has_static
        if not swap.any() and not new.any():
            return hits
        tri, dist, normal = hits.tri.copy(), hits.dist.copy(), hits.normal.copy()
        refl, material = hits.reflectance.copy(), hits.material.copy()
        at = pos[swap]
        tri[at], dist[at], normal[at] = -1, dist_d[swap], normal_d[swap]
        refl[at], material[at] = refl_d[swap], mat_d[swap]
        ray = hits.ray
        if new.any():  # rays that hit only a dynamic object: merged in ray order
            ray = np.concatenate([ray, ray_d[new]])
            order = np.argsort(ray, kind="stable")
            ray = ray[order]
            tri = np.concatenate([tri, np.full(new.sum(), -1, dtype=tri.dtype)])[order]
            dist = np.concatenate([dist, dist_d[new]])[order]
            normal = np.concatenate([normal, normal_d[new]])[order]
            refl = np.concatenate([refl, refl_d[new].astype(refl.dtype)])[order]
            material = np.concatenate([material, mat_d[new]])[order]
        return Hits(tri, ray, dist, normal, refl, material)


class GroundModel:
    """Ground height at (x, y): inverse-distance blend of points `sensor_height` below the poses, plus
    mild seeded relief that fades in away from the road."""

    def __init__(self, poses: np.ndarray, sensor_height: float, rng: np.random.Generator) -> None:
        below = poses[:, :3, 3] - sensor_height * poses[:, :3, 2]
        keep = np.concatenate([[True], np.linalg.norm(np.diff(below[:, :2], axis=0), axis=1) > 1e-3])
        self.anchors = below[keep]
        self.tree = cKDTree(self.anchors[:, :2])
        self.k = min(8, len(self.anchors))
        self.waves = rng.uniform([0.02, 0.0, 0.0], [0.08, 2 * np.pi, 2 * np.pi], size=(4, 3))
        self.amp = rng.uniform(0.05, 0.12, size=4)

    def __call__(self, xy: np.ndarray) -> float:
        """The ground height at one point (x, y)."""
        return float(self.heights(xy)[0])

    def heights(self, xy: np.ndarray) -> np.ndarray:
        """The ground heights at the points `xy` (N, 2)."""
        pts = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        dist, idx = self.tree.query(pts, k=self.k)
        dist, idx = dist.reshape(len(pts), -1), idx.reshape(len(pts), -1)
        w = 1.0 / (dist + 0.5) ** 2
        z = (w * self.anchors[idx, 2]).sum(1) / w.sum(1)
        k, theta, phase = self.waves[:, 0], self.waves[:, 1], self.waves[:, 2]
        proj = pts[:, :1] * np.cos(theta) + pts[:, 1:2] * np.sin(theta)
        relief = (self.amp * np.sin(2 * np.pi * k * proj + phase)).sum(1)
        z = z + relief * np.clip((dist[:, 0] - 4.0) / 10.0, 0.0, 1.0)
        return z


def extend_path(xy: np.ndarray, length: float) -> np.ndarray:
    """`xy` continued straight for `length` metres before its start and after its end, so the first and
    last scans see a street around them too (as a real drive that began and ended elsewhere)."""

    def heading(a: np.ndarray) -> np.ndarray:
        far = a[np.argmax(np.linalg.norm(a - a[0], axis=1) > 5.0)] if len(a) > 1 else a[0]
        d = far - a[0]
        n = np.linalg.norm(d)
        return d / n if n > 1e-6 else np.array([1.0, 0.0])

    steps = np.arange(length, 0.0, -1.0)[:, None]
    before = xy[0] - steps * heading(xy)
    after = xy[-1] - steps[::-1] * heading(xy[::-1])
    return np.concatenate([before, xy, after])


def build_world(
    poses: np.ndarray,
    style: str = "city",
    seed: int = 0,
    sensor_height: float = 1.73,
    realism: WorldRealism = WorldRealism(),
    up: np.ndarray | None = None,
    times: np.ndarray | None = None,
) -> World:
    """The world around `poses` (N, 4, 4): same seed, poses and realism give the same world, triangle for
    triangle and object for object. The realism features draw from their own seeded streams. An upright
    world stands along `up` (gravity in the poses' frame; default: level.gravity_up of `poses`). `times` (N,)
    are the poses' times on the clock `World.cast` is given (default: 10 Hz from 0): traffic keeps its distance
    from the ego where the ego is at that time."""
    if style not in STYLES:
        raise InputError(f"unknown world style {style!r}; choose one of {', '.join(STYLES)}")
    levelling = None
    if realism.upright:
        up = gravity_up(poses) if up is None else np.asarray(up, dtype=np.float64)
        if tilt_deg(up) >= LEVEL_DEG:
            levelling = levelling_rotation(up)
            poses = poses.copy()
            poses[:, :3, :] = np.einsum("ij,njk->nik", levelling, poses[:, :3, :])
    st = STYLES[style]
    if realism.parked_occupancy > 0 and st.p_parked > 0:  # a style without parking (campus) keeps none
        st = replace(st, p_parked=realism.parked_occupancy)
    if not realism.right_hand_traffic:  # the plain world's street is symmetric about the path
        st = replace(st, two_way=False)
    rng = np.random.default_rng(seed)
    ground = GroundModel(poses, sensor_height, rng)
    xy = extend_path(poses[:, :2, 3], PATH_LEAD)
    path = PathFrame.of(xy)
    designs = realism.designs_for(sum(b - a for a, b in first_visits(xy)))
    plan = plan_stretches(
        xy,
        realism.catalogue_share,
        realism.hard_share,
        realism.hard_kinds,
        designs,
        np.random.default_rng([seed, 12, 1]),
        hard_from=PATH_LEAD + START_STRUCTURE_M,
    )
    catalogue = make_catalogue(designs, st, np.random.default_rng([seed, 12, 2]), realism.design_variants)
    layout = StreetLayout(xy, st, rng, ground, plan, catalogue, realism.transient_parking)
    layout.build()
    builder = MeshBuilder()
    layout.emit(builder)
    lo = xy.min(0) - st.ground_radius
    n = np.ceil((xy.max(0) + st.ground_radius - lo) / st.ground_cell).astype(int)
    gy, gx = np.mgrid[0 : n[1] + 1, 0 : n[0] + 1]
    grid = np.column_stack([lo[0] + gx.ravel() * st.ground_cell, lo[1] + gy.ravel() * st.ground_cell])
    centres = grid.reshape(n[1] + 1, n[0] + 1, 2)[:-1, :-1] + st.ground_cell / 2
    near, _ = layout.clear.tree.query(centres.reshape(-1, 2), distance_upper_bound=st.ground_radius)
    keep = np.isfinite(near).reshape(n[1], n[0])
    builder.height_field(lo, st.ground_cell, ground.heights(grid).reshape(n[1] + 1, n[0] + 1), keep, 0.25)
    mesh, reflectance, material = builder.build()
    recipe = DynamicRecipe(
        realism.moving_cars if st.p_parked > 0 else 0.0,
        realism.pedestrians,
        st.oncoming_lane,
        st.pedestrian_offset,
        realism.turnover_period,
        st.left_shift,
    )
    times = np.arange(len(poses)) / 10.0 if times is None else np.asarray(times, dtype=np.float64)
    if times.shape != (len(poses),):
        raise InputError(f"build_world: {len(times)} times for {len(poses)} poses; give one time a pose")
    first = (len(xy) - len(poses)) // 2  # extend_path adds as many points before the poses as after them
    dynamic = make_dynamic(
        path,
        ground.heights,
        recipe,
        np.array(layout.transient).reshape(-1, 11),
        Road(path, st.ego_half, layout.clear, layout.taken),
        EgoClock(times, path.arc[first : first + len(poses)]),
        np.random.default_rng([seed, 12, 3]),
        seed,
    )
    return World(mesh, reflectance, material, dynamic, realism, seed, plan, levelling)
