"""Procedural placement of street-side structure along a trajectory (one seeded world per sequence).

Each side of the path is walked by arc length: a block (varied footprint, height, setback, relief on the
facade that faces the path), then a gap (empty, a wall, or trees); poles, trees and parked cars in
between. Every object is rejected if its footprint comes closer than a clearance to ANY trajectory point
(so the road stays clear where the path crosses or doubles back) or if it overlaps an object already
placed (so a revisited place keeps what was built on the first pass: same place, same look).
With a `plan` (see `plan`), designed and hard stretches are laid first and the block walk skips them;
parked cars may be transient (kept apart for `dynamic`, present only in some time windows).
A two-way street (`Style.two_way`, with `world.WorldRealism.right_hand_traffic`) is driven in its right lane: every
offset to the left of the path is one lane (`Style.left_shift`) larger than its mirror image on the right.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from msa_slam.sim.plan import DESIGN, Design, Stretch
from msa_slam.sim.shapes import Material, MeshBuilder
from msa_slam.sim.stretches import PlannedStretches


@dataclass(frozen=True)
class Style:
    """Street-scene parameters, metres, the same on both sides of the path but for `left_shift`. `city` for
    vehicles (KITTI-like: two-way streets), `campus` for slow platforms (walkways)."""

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
    # m: a lane's width, so the oncoming lane's centre left of the path (right-hand traffic); RASt 06, Germany's
    # guidelines for urban streets, gives about 3.0-3.5 m a lane
    oncoming_lane: float = 3.0
    ego_half: tuple[float, float] = (2.5, 1.0)  # the ego's footprint about the sensor: KITTI's 4.8 x 1.8 m estate car
    two_way: bool = False  # a two-way street driven in its right lane: see `left_shift`

    @property
    def left_shift(self) -> float:
        """How much farther out the left side stands than the right (m). A two-way street is driven in its right
        lane (right-hand traffic, as KITTI's Germany): the path is that lane's centre and the carriageway goes on
        one lane (`oncoming_lane`) to the left, so the left row of parked cars, kerb, footpath, poles, trees and
        buildings stand that much farther out than their mirror images on the right. A street for one lane of
        traffic, or a walkway (the campus style: the walker keeps to its middle), is symmetric: 0."""
        return self.oncoming_lane if self.two_way else 0.0


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
        two_way=True,
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
        super().__init__(xy, style, rng, ground_height, transient)
        self.plan = tuple(plan)
        self._starts = [p.start for p in self.plan]
        self.catalogue = tuple(catalogue)

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
                    self._beside(p, n, side, off),
                    (length / 2, 0.15),
                    yaw,
                    self._u((0.8, 2.5)),
                    self._u((0.3, 0.6)),
                    st.road_clearance,
                )
            elif kind < 0.65 and length > 2:
                self._add_box(
                    self._beside(p, n, side, off),
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
                    self._tree(self._beside(q, m, side, off + self._u((0.0, 3.0))), st.road_clearance)
            return length
        length, depth = self._u(st.length), self._u(st.depth)
        p, h, n = self._at(s + length / 2)
        yaw = float(np.arctan2(h[1], h[0]))
        setback = self._u(st.setback)
        center = self._beside(p, n, side, setback + depth / 2)
        if self._building(center, yaw, side, length, depth, st.road_clearance):
            if self.rng.random() < st.p_back_row:
                back_depth = self._u(st.depth)
                back = center + side * n * (depth / 2 + self._u((2.0, 8.0)) + back_depth / 2)
                self._building(back, yaw, side, self._u(st.length), back_depth, st.road_clearance, height_scale=1.5)
        return length + self._u((0.3, 1.5))

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
                c = self._beside(p, n, side, self._u((st.car_offset[1] + 0.7, st.setback[0] - 0.5)))
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
                    c = self._beside(p, n, side, self._u((st.car_offset[1] + 1.0, st.setback[1])))
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
