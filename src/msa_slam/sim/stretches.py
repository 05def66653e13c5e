"""Planned stretches of a street layout (see `plan`): rows of a catalogue design's house types, and
hard stretches (open field, plain walls, tunnel, highway) that constrain ICP little along the path.
A base of `layout.StreetLayout`, drawn with the primitives of `placement.Placement`."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from msa_slam.sim.placement import Placement
from msa_slam.sim.plan import DESIGN, ORDER_LENGTH, Design, HouseVariant, Stretch
from msa_slam.sim.shapes import Material

ROW_BEYOND_M = 60.0
ROW_CLEAR_M = 15.0


class PlannedStretches(Placement):
    """Designed rows and hard stretches, placed with Placement's primitives along StreetLayout's `plan`."""

    plan: tuple[Stretch, ...]  # set by StreetLayout

    @contextmanager
    def _seeded(self, *seed: int) -> Iterator[None]:
        """Draw from a fixed stream meanwhile: every instance of a design gets the same details."""
        saved, self.rng = self.rng, np.random.default_rng(list(seed))
        try:
            yield
        finally:
            self.rng = saved

    def _row_at(self, stretch: Stretch, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Point, heading and left normal at arc length s of the path inside the stretch, and on the straight
        line continuing it beyond its ends (the designed street goes on past the junction where the path turns)."""
        end = min(max(s, stretch.start), stretch.end)
        p, h, n = self._at(end)
        return p + h * (s - end), h, n

    def _row_span(self, stretch: Stretch) -> tuple[float, float]:
        """Where a design's rows go: the stretch and up to ROW_BEYOND_M past each end, short of the neighbouring
        hard stretches (Scan Context sees 80 m ahead: without the street going on, two places of one design
        differ by where their street ends). Houses of two designs meeting at a corner: the first laid stays."""
        hard = [o for o in self.plan if o.kind != DESIGN]
        before = max((o.end for o in hard if o.end <= stretch.start), default=-np.inf)
        after = min((o.start for o in hard if o.start >= stretch.end), default=np.inf)
        return (
            max(stretch.start - ROW_BEYOND_M, before + ROW_CLEAR_M),
            min(stretch.end + ROW_BEYOND_M, after - ROW_CLEAR_M),
        )

    def _design_row(self, stretch: Stretch, design: Design, side: float) -> None:
        """The design's houses, their types in the design's order from the instance's starting point, one garden
        gap apart and centred in the row's span, with the design's garden walls, back-row blocks, fence,
        front-garden trees, parked cars and street lights."""
        st = self.style
        start, end = self._row_span(stretch)
        gap = design.pitch - design.length
        order = design.variant_order()
        first = stretch.order_offset + (0 if side > 0 else ORDER_LENGTH // 2)  # the far side has its own run
        houses: list[HouseVariant] = []
        row = -gap
        while row + gap + (house := design.house(order, first + len(houses))).length <= end - start:
            houses.append(house)
            row += gap + house.length
        s = start + max(end - start - row, 0.0) / 2  # centred: the row is the same driven either way

        def at(x: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            return self._row_at(stretch, x)

        gaps = []
        for k, house in enumerate(houses):
            p, h, n = at(s + house.length / 2)
            yaw = float(np.arctan2(h[1], h[0]))
            center = self._beside(p, n, side, design.setback + design.depth / 2)
            with self._seeded(design.detail_seed, 0):
                built = self._building(
                    center,
                    yaw,
                    side,
                    house.length,
                    design.depth,
                    st.road_clearance,
                    height=house.height,
                    refl=design.refl,
                )
                if built and house.back is not None:
                    length, depth, height = house.back
                    back = center + side * n * (design.depth / 2 + 4.0 + depth / 2)
                    self._building(
                        back, yaw, side, length, depth, st.road_clearance, height=height, refl=design.refl * 0.9
                    )
            plot = house.length + gap
            if design.fence > 0:
                q, _, m = at(s + plot / 2)
                self._add_box(
                    self._beside(q, m, side, design.setback - 1.0),
                    (plot / 2 - 0.2, 0.08),
                    yaw,
                    design.fence,
                    0.5,
                    st.road_clearance - 1.0,
                )
            if house.tree:
                q, _, m = at(s + house.length + gap / 2)
                with self._seeded(design.detail_seed, 1):
                    self._tree(self._beside(q, m, side, design.setback + 1.0), st.road_clearance)
            if st.p_parked > 0:  # the same cars in front of every house of the design
                with self._seeded(design.detail_seed, 2):
                    for x in np.arange(self._u((0.0, 3.0)), plot - 4.0, 6.5):
                        if self.rng.random() < st.p_parked:
                            self._parked_car(s + x, side, False, at)
            if design.light_pitch and k % design.light_pitch == 0:
                q, _, m = at(s)
                c = self._beside(q, m, side, st.car_offset[1] + 0.7)
                if self._try(c, np.array([0.2, 0.2]), 0.0, st.furniture_clearance):
                    self.trunks.append((*c, self.ground(c) - 0.3, 0.12, 6.5, 0.8))
            if k < len(houses) - 1:
                gaps.append(s + house.length)
            s += plot
        if design.gap_wall > 0 and gap > 0.5:  # after the houses, which keep a margin to anything placed before
            for x in gaps:
                q, h, m = at(x + gap / 2)
                self._wall_piece(
                    self._beside(q, m, side, design.setback + design.depth / 2),
                    (gap / 2, 0.15),
                    float(np.arctan2(h[1], h[0])),
                    self.ground(q) - 0.3,
                    design.gap_wall + 0.3,
                    design.refl * 0.8,
                    overlap=0.6,
                )  # on a bend the inner side's gaps narrow

    def _segments(self, stretch: Stretch, step: float) -> Iterator[tuple[float, np.ndarray, np.ndarray, float]]:
        """(arc length, point, left normal, yaw) every `step` m along the stretch (segment centres)."""
        for s in np.arange(stretch.start + step / 2, stretch.end, step):
            p, h, n = self._at(float(s))
            yield float(s), p, n, float(np.arctan2(h[1], h[0]))

    def _wall_piece(
        self,
        center: np.ndarray,
        half: tuple[float, float],
        yaw: float,
        z0: float,
        height: float,
        refl: float,
        material: int = Material.SOLID,
        overlap: float = 0.05,
    ) -> None:
        """One piece of a continuous structure: kept off every other road, placed where it overlaps what is
        already there by at most `overlap` m (its neighbours, or the houses a garden wall joins)."""
        h = np.asarray(half, float)
        if self.clear.is_clear(center, h, yaw, self.style.furniture_clearance) and self.taken.add_if_free(
            center, h, yaw, margin=-overlap
        ):
            self.boxes.append((*center, z0 + height / 2, *h, height / 2, yaw, refl, material))

    def _hard(self, stretch: Stretch) -> None:
        """Structure that constrains little along the path: an open field with a few far trees, plain walls,
        a tunnel (walls and a roof) or a highway between low barriers. A two-way street's left side stands one
        lane farther out (`Style.left_shift`) in fields, between walls and in tunnels (a tunnel with a lane each
        way); the highway's barriers are laid for it already."""
        st = self.style
        kind = stretch.kind
        if kind == "field":
            s = stretch.start + self._u((5.0, 30.0))
            while s < stretch.end:
                p, _, n = self._at(s)
                side = 1.0 if self.rng.random() < 0.5 else -1.0
                self._tree(self._beside(p, n, side, self._u((18.0, 45.0))), st.road_clearance)
                s += self._u((20.0, 45.0))
            return
        step = 4.0
        lateral = st.road_clearance + 0.5
        wall_h = self._u((3.0, 6.0))
        roof = self._u((4.5, 5.5)) if st.p_parked > 0 else self._u((2.8, 3.4))
        refl = self._u((0.3, 0.6))
        for s, p, n, yaw in self._segments(stretch, step):
            z = self.ground(p)
            if kind in ("wall", "tunnel"):
                for side in (1.0, -1.0):
                    self._wall_piece(
                        self._beside(p, n, side, lateral + 0.15),
                        (step / 2, 0.15),
                        yaw,
                        z - 0.5,
                        (roof if kind == "tunnel" else wall_h) + 0.5,
                        refl,
                    )
                if kind == "tunnel":  # the roof spans the walls: centred between them
                    half = np.array([step / 2, lateral + 0.5 + st.left_shift / 2])
                    c = p + n * st.left_shift / 2
                    if self.clear.only_within(c, half, yaw, stretch.start - 10.0, stretch.end + 10.0):
                        self.boxes.append((*c, z + roof + 1.5, *half, 1.5, yaw, refl, Material.SOLID))
            else:  # highway: a concrete barrier each side, a light pole on the left every 40 m; its carriageway
                # already has a lane left of the ego's (barriers 3.3 m right, 5.8 m left): no left shift
                for side, off in ((1.0, lateral + 0.3), (-1.0, st.car_offset[0])):
                    self._wall_piece(p + side * n * off, (step / 2, 0.3), yaw, z - 0.2, 1.0, 0.45)
                if int(s // 40.0) != int((s - step) // 40.0):
                    c = p + n * (lateral + 1.2)
                    if self._try(c, np.array([0.2, 0.2]), 0.0, st.furniture_clearance):
                        self.trunks.append((*c, z - 0.3, 0.12, 9.0, 0.8))
