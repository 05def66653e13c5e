"""Procedural placement of street-side structure along a trajectory (one seeded world per sequence).

Each side of the path is walked by arc length: a block (varied footprint, height, setback, relief on the
facade that faces the path), then a gap (empty, a wall, or trees); poles, trees and parked cars in
between. Every object is rejected if its footprint comes closer than a clearance to ANY trajectory point
(so the road stays clear where the path crosses or doubles back) or if it overlaps an object already
placed (so a revisited place keeps what was built on the first pass: same place, same look).
With a `plan` (see `plan`), designed and hard stretches are laid first and the block walk skips them;
parked cars may be transient (kept apart for `dynamic`, present only in some time windows).
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from msa_slam.sim.footprints import Footprints, PathClearance, yaw_axes
from msa_slam.sim.plan import DESIGN, Design, Stretch
from msa_slam.sim.shapes import Material, MeshBuilder
from msa_slam.sim.stretches import PlannedStretches


@dataclass(frozen=True)
class Style:
    """Street-scene parameters, metres. `city` for vehicles (KITTI-like), `campus` for slow platforms."""

    name: str
    road_clearance: float  # no block footprint closer than this to any trajectory point
    setback: tuple[float, float]  # near facade distance from the path
    length: tuple[float, float]  # block length along the street
    depth: tuple[float, float]  # block depth away from the street
    height: tuple[float, float]
    gap: tuple[float, float]
    p_gap: float  # probability of a gap after a block
    p_back_row: float  # probability of a taller block behind the front
    pole_spacing: float
    tree_spacing: float
    p_parked: float  # probability per car slot of a parked car
    car_offset: tuple[float, float]
    furniture_clearance: float
    ground_radius: float  # ground extends this far from the path
    ground_cell: float
    pedestrian_offset: tuple[float, float] = (5.3, 6.6)  # walkers' distance from the path
    oncoming_lane: float = 3.0  # m, the oncoming lane's centre left of the path (right-hand traffic): a lane width
    ego_half: tuple[float, float] = (2.5, 1.0)  # the ego's footprint about the sensor: KITTI's 4.8 x 1.8 m estate car


STYLES: dict[str, Style] = {
    "city": Style(
        "city",
        5.0,
        (7.0, 12.0),
        (6.0, 24.0),
        (8.0, 20.0),
        (4.0, 25.0),
        (2.0, 8.0),
        0.3,
        0.35,
        30.0,
        14.0,
        0.5,
        (3.3, 4.3),
        2.3,
        70.0,
        2.5,
    ),
    "campus": Style(
        "campus",
        2.0,
        (3.5, 7.0),
        (8.0, 30.0),
        (6.0, 14.0),
        (4.0, 15.0),
        (2.0, 8.0),
        0.2,
        0.3,
        18.0,
        7.0,
        0.0,
        (1.6, 2.2),
        1.2,
        45.0,
        1.5,
        pedestrian_offset=(0.8, 2.2),
        ego_half=(0.3, 0.3),  # a person or a small robot
    ),
}


class StreetLayout(PlannedStretches):
    """Places blocks and street furniture along a path; primitives go to a MeshBuilder."""

    def __init__(
        self,
        xy: np.ndarray,
        style: Style,
        rng: np.random.Generator,
        ground_height: Callable[[np.ndarray], float],
        plan: Sequence[Stretch] = (),
        catalogue: Sequence[Design] = (),
        transient: float = 0.0,
    ) -> None:
        self.style = style
        self.rng = rng
        self.ground = ground_height
        self.clear = PathClearance(xy)
        self.taken = Footprints()
        self.plan = tuple(plan)
        self._starts = [p.start for p in self.plan]
        self.catalogue = tuple(catalogue)
        self.transient_share = transient
        self.transient: list[tuple[float, ...]] = []  # parked cars that come and go, see `dynamic`
        self.boxes: list[tuple[float, ...]] = []  # cx, cy, cz, hx, hy, hz, yaw, refl, material
        self.trunks: list[tuple[float, ...]] = []  # x, y, z, radius, height, refl
        self.crowns: list[tuple[float, ...]] = []  # x, y, z, rx, ry, rz, refl
        seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        self.arc = np.concatenate([[0.0], np.cumsum(seg)])
        self.xy = xy

    def _at(self, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Point, unit heading and unit left normal at arc length s."""
        p = np.array([np.interp(s, self.arc, self.xy[:, 0]), np.interp(s, self.arc, self.xy[:, 1])])
        q = np.array([np.interp(s + 2.0, self.arc, self.xy[:, 0]), np.interp(s + 2.0, self.arc, self.xy[:, 1])])
        r = np.array([np.interp(s - 2.0, self.arc, self.xy[:, 0]), np.interp(s - 2.0, self.arc, self.xy[:, 1])])
        h = q - r
        h = h / max(np.linalg.norm(h), 1e-9)
        return p, h, np.array([-h[1], h[0]])

    def _try(self, center: np.ndarray, half: np.ndarray, yaw: float, clearance: float) -> bool:
        return self.clear.is_clear(center, half, yaw, clearance) and self.taken.add_if_free(center, half, yaw)

    def _u(self, lo_hi: tuple[float, float]) -> float:
        return float(self.rng.uniform(*lo_hi))

    def _special(self, s: float) -> Stretch | None:
        """The planned stretch containing arc length s, if any."""
        k = bisect.bisect_right(self._starts, s) - 1
        return self.plan[k] if k >= 0 and s < self.plan[k].end else None

    def build(self) -> None:
        total = self.arc[-1]
        for stretch in self.plan:
            if stretch.kind == DESIGN:
                for side in (1.0, -1.0):
                    self._design_row(stretch, self.catalogue[stretch.design], side)
            else:
                self._hard(stretch)
        for side in (1.0, -1.0):
            s = self._u((0.0, 10.0))
            while s < total:
                special = self._special(s) if self.plan else None
                if special is not None:
                    s = special.end
                    continue
                s += self._block_or_gap(s, side)
        self._furniture(total)

    def _block_or_gap(self, s: float, side: float) -> float:
        st = self.style
        if self.rng.random() < st.p_gap:  # a gap: a wall or fence, a hedge, a row of trees, or nothing
            length = self._u(st.gap)
            kind = self.rng.random()
            p, h, n = self._at(s + length / 2)
            yaw = float(np.arctan2(h[1], h[0]))
            off = self._u(st.setback)
            if kind < 0.4 and length > 2:
                self._add_box(
                    p + side * n * off,
                    (length / 2, 0.15),
                    yaw,
                    self._u((0.8, 2.5)),
                    self._u((0.3, 0.6)),
                    st.road_clearance,
                )
            elif kind < 0.65 and length > 2:
                self._add_box(
                    p + side * n * off,
                    (length / 2, 0.5),
                    yaw,
                    self._u((0.8, 1.6)),
                    0.2,
                    st.road_clearance,
                    material=Material.VEGETATION,
                )  # a hedge
            elif kind < 0.85:
                for x in np.arange(1.0, length, self._u((3.0, 5.0))):
                    q, _, m = self._at(s + x)
                    self._tree(q + side * m * (off + self._u((0.0, 3.0))), st.road_clearance)
            return length
        length, depth = self._u(st.length), self._u(st.depth)
        p, h, n = self._at(s + length / 2)
        yaw = float(np.arctan2(h[1], h[0]))
        setback = self._u(st.setback)
        center = p + side * n * (setback + depth / 2)
        if self._building(center, yaw, side, length, depth, st.road_clearance):
            if self.rng.random() < st.p_back_row:
                back_depth = self._u(st.depth)
                back = center + side * n * (depth / 2 + self._u((2.0, 8.0)) + back_depth / 2)
                self._building(back, yaw, side, self._u(st.length), back_depth, st.road_clearance, height_scale=1.5)
        return length + self._u((0.3, 1.5))

    def _add_box(
        self,
        center: np.ndarray,
        half_xy: tuple[float, float],
        yaw: float,
        height: float,
        refl: float,
        clearance: float,
        sink: float = 0.5,
        material: int = Material.SOLID,
    ) -> bool:
        half = np.asarray(half_xy, float)
        if not self._try(center, half, yaw, clearance):
            return False
        z0 = self.ground(center) - sink
        self.boxes.append((*center, z0 + (height + sink) / 2, *half, (height + sink) / 2, yaw, refl, material))
        return True

    def _building(
        self,
        center: np.ndarray,
        yaw: float,
        side: float,
        length: float,
        depth: float,
        clearance: float,
        height_scale: float = 1.0,
        height: float | None = None,
        refl: float | None = None,
    ) -> bool:
        """A block with relief on the facade facing the path: pilasters, balconies, a stepped top.
        Height and reflectance are drawn unless given (a catalogue design fixes them)."""
        st = self.style
        if height is None:
            height = min(self._u(st.height) * height_scale, st.height[1] * 1.4)
        if refl is None:
            refl = self._u((0.35, 0.75))
        if not self._add_box(center, (length / 2, depth / 2), yaw, height, refl, clearance):
            return False
        ex, ey = yaw_axes(yaw)
        base = self.ground(center) - 0.5
        near = center - side * ey * depth / 2  # facade facing the path
        x = -length / 2 + self._u((0.5, 3.0))
        while x < length / 2 - 0.5:  # pilasters at irregular spacing
            w, d = self._u((0.3, 0.9)), self._u((0.25, 0.8))
            top = height if self.rng.random() < 0.6 else self._u((2.5, height))
            c = near + ex * x - side * ey * d / 2
            self.boxes.append((*c, base + top / 2, w / 2, d / 2, top / 2, yaw, refl * 0.9, Material.SOLID))
            x += self._u((1.8, 6.0))
        floors = int(height // 3.0)
        if floors >= 2 and self.rng.random() < 0.5:  # balconies on a few floors
            for k in range(1, floors):
                if self.rng.random() < 0.5:
                    continue
                for x in np.arange(-length / 2 + 2.0, length / 2 - 2.0, self._u((4.0, 8.0))):
                    c = near + ex * x - side * ey * 0.6
                    self.boxes.append(
                        (*c, base + 0.5 + 3.0 * k, self._u((0.8, 1.8)), 0.6, 0.5, yaw, refl, Material.SOLID)
                    )
        if height > 8 and self.rng.random() < 0.5:  # stepped upper storey
            c = center + side * ey * depth * 0.15
            extra = self._u((2.0, 6.0))
            self.boxes.append(
                (*c, base + height + extra / 2, length * 0.35, depth * 0.3, extra / 2, yaw, refl, Material.SOLID)
            )
        return True

    def _tree(self, c: np.ndarray, clearance: float) -> None:
        """A trunk and an irregular crown."""
        crown = self._u((1.2, 3.0))
        if self._try(c, np.array([0.6, 0.6]), 0.0, clearance):
            trunk_h = self._u((1.8, 4.0))
            z = self.ground(c) - 0.3
            self.trunks.append((*c, z, self._u((0.12, 0.3)), trunk_h + crown * 0.5, 0.3))
            self.crowns.append(
                (*c, z + trunk_h + crown * 0.8, crown, crown * self._u((0.8, 1.2)), crown * self._u((0.7, 1.3)), 0.25)
            )

    def _furniture(self, total: float) -> None:
        """Poles, trees and parked cars; designed stretches bring their own, hard stretches have none."""
        st = self.style
        for side in (1.0, -1.0):
            s = self._u((0.0, st.pole_spacing))
            while s < total:  # poles
                if self.plan and self._special(s) is not None:
                    s += st.pole_spacing
                    continue
                p, h, n = self._at(s)
                c = p + side * n * self._u((st.car_offset[1] + 0.7, st.setback[0] - 0.5))
                if self._try(c, np.array([0.2, 0.2]), 0.0, st.furniture_clearance):
                    self.trunks.append((*c, self.ground(c) - 0.3, self._u((0.08, 0.18)), self._u((4.5, 8.0)), 0.8))
                s += st.pole_spacing * self._u((0.6, 1.4))
            s = self._u((0.0, st.tree_spacing))
            while s < total:  # trees
                if self.plan and self._special(s) is not None:
                    s += st.tree_spacing
                    continue
                if self.rng.random() < 0.6:
                    p, h, n = self._at(s)
                    c = p + side * n * self._u((st.car_offset[1] + 1.0, st.setback[1]))
                    self._tree(c, st.furniture_clearance + 0.5)
                s += st.tree_spacing * self._u((0.5, 1.5))
            if st.p_parked <= 0:
                continue
            s = self._u((0.0, 10.0))
            while s < total:  # parked cars
                special = self._special(s) if self.plan else None
                if special is None:  # designed stretches park their own cars, hard ones none
                    if self.rng.random() < st.p_parked:
                        self._parked_car(s, side, self.transient_share > 0 and self.rng.random() < self.transient_share)
                    elif self.transient_share > 0 and self.rng.random() < self.transient_share * st.p_parked:
                        self._parked_car(s, side, True)  # an empty slot, taken at some times
                s += self._u((5.0, 7.5))

    def _parked_car(
        self,
        s: float,
        side: float,
        transient: bool,
        at: Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
    ) -> None:
        """Body and cabin at arc length s (of the path, or of the street `at` gives); a transient car goes to
        `self.transient` (x, y, z, yaw, body half length and width, cabin centre height above ground and half
        extents, reflectance) and keeps its footprint reserved."""
        st = self.style
        p, h, n = (at or self._at)(s)
        yaw = float(np.arctan2(h[1], h[0]))
        c = p + side * n * self._u(st.car_offset)
        half = np.array([self._u((1.9, 2.4)), self._u((0.8, 0.95))])
        if not self._try(c, half, yaw, st.furniture_clearance):
            return
        z = self.ground(c)
        refl = self._u((0.3, 0.9))
        cab = self._u((1.3, 1.5))
        cabin = (1.05 + cab * 0.25, half[0] * 0.55, half[1] * 0.9, cab * 0.25)
        if transient:
            self.transient.append((*c, z, yaw, *half, *cabin, refl))
            return
        self.boxes.append((*c, z + 0.2 + 0.4, *half, 0.45, yaw, refl, Material.VEHICLE))
        self.boxes.append((*c, z + 1.05 + cab * 0.25, *cabin[1:], yaw, refl, Material.VEHICLE))

    def emit(self, builder: MeshBuilder) -> None:
        if self.boxes:
            b = np.array(self.boxes)
            builder.boxes(b[:, :3], b[:, 3:6], b[:, 6], b[:, 7], b[:, 8].astype(np.uint8))
        if self.trunks:
            t = np.array(self.trunks)
            builder.prisms(t[:, :3], t[:, 3], t[:, 4], t[:, 5])
        if self.crowns:
            c = np.array(self.crowns)
            builder.blobs(c[:, :3], c[:, 3:6], c[:, 6], self.rng)
