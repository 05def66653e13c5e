"""The placement primitives of a street layout (`layout.StreetLayout`, `stretches.PlannedStretches`): the path by
arc length, seeded draws, footprints kept clear of the path and of each other, and the objects placed (blocks,
trees, parked cars) as boxes, trunks and crowns."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from msa_slam.sim.footprints import Footprints, PathClearance, yaw_axes
from msa_slam.sim.shapes import Material

if TYPE_CHECKING:
    from msa_slam.sim.layout import Style


class Placement:
    """What is placed along the path `xy` so far, and how one more object is placed."""

    def __init__(
        self,
        xy: np.ndarray,
        style: Style,
        rng: np.random.Generator,
        ground_height: Callable[[np.ndarray], float],
        transient: float = 0.0,
    ) -> None:
        self.style = style
        self.rng = rng
        self.ground = ground_height
        self.clear = PathClearance(xy)
        self.taken = Footprints()
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

    def _beside(self, p: np.ndarray, n: np.ndarray, side: float, offset: float) -> np.ndarray:
        """The point `offset` m to one side (`side` +1: left, -1: right) of path point `p` (unit left normal `n`),
        a two-way street's left side one lane farther out (`Style.left_shift`)."""
        return p + side * n * (offset + (self.style.left_shift if side > 0 else 0.0))

    def _try(self, center: np.ndarray, half: np.ndarray, yaw: float, clearance: float) -> bool:
        return self.clear.is_clear(center, half, yaw, clearance) and self.taken.add_if_free(center, half, yaw)

    def _u(self, lo_hi: tuple[float, float]) -> float:
        return float(self.rng.uniform(*lo_hi))

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
        c = self._beside(p, n, side, self._u(st.car_offset))
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
