"""Where structure may go: placed footprints (oriented rectangles that must not overlap) and the clearance
every footprint keeps from every point of the trajectory (so the road stays clear where the path crosses
or doubles back)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


class Footprints:
    """Oriented rectangles on a spatial hash; answers "does this rectangle overlap a placed one?"."""

    def __init__(self, cell: float = 10.0) -> None:
        self.cell = cell
        self.rects: list[tuple[np.ndarray, np.ndarray, float]] = []
        self.grid: dict[tuple[int, int], list[int]] = {}

    def _cells(self, center: np.ndarray, radius: float) -> list[tuple[int, int]]:
        lo = np.floor((center - radius) / self.cell).astype(int)
        hi = np.floor((center + radius) / self.cell).astype(int)
        return [(i, j) for i in range(lo[0], hi[0] + 1) for j in range(lo[1], hi[1] + 1)]

    @staticmethod
    def _overlap(
        a: tuple[np.ndarray, np.ndarray, float], b: tuple[np.ndarray, np.ndarray, float], margin: float
    ) -> bool:
        axes = [np.array([np.cos(t), np.sin(t)]) for t in (a[2], a[2] + np.pi / 2, b[2], b[2] + np.pi / 2)]
        d = b[0] - a[0]
        for ax in axes:
            ra = sum(h * abs(np.dot(ax, u)) for h, u in zip(a[1], yaw_axes(a[2])))
            rb = sum(h * abs(np.dot(ax, u)) for h, u in zip(b[1], yaw_axes(b[2])))
            if abs(np.dot(d, ax)) > ra + rb + margin:
                return False
        return True

    def is_free(self, center: np.ndarray, half: np.ndarray, yaw: float, margin: float = 0.3) -> bool:
        """True when the rectangle keeps `margin` from every placed one."""
        rect = (np.asarray(center, float), np.asarray(half, float), float(yaw))
        seen: set[int] = set()
        for c in self._cells(rect[0], float(np.hypot(*half)) + margin):
            for idx in self.grid.get(c, ()):
                if idx not in seen:
                    seen.add(idx)
                    if self._overlap(rect, self.rects[idx], margin):
                        return False
        return True

    def add_if_free(self, center: np.ndarray, half: np.ndarray, yaw: float, margin: float = 0.3) -> bool:
        if not self.is_free(center, half, yaw, margin):
            return False
        self.add(center, half, yaw, margin)
        return True

    def add(self, center: np.ndarray, half: np.ndarray, yaw: float, margin: float = 0.3) -> None:
        """Register a rectangle without checking (pieces of one continuous wall touch each other)."""
        self.rects.append((np.asarray(center, float), np.asarray(half, float), float(yaw)))
        for c in self._cells(self.rects[-1][0], float(np.hypot(*half)) + margin):
            self.grid.setdefault(c, []).append(len(self.rects) - 1)


def yaw_axes(yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit x and y axes of a rectangle turned by `yaw`."""
    return np.array([np.cos(yaw), np.sin(yaw)]), np.array([-np.sin(yaw), np.cos(yaw)])


def rect_gaps(
    a_centre: np.ndarray,
    a_half: np.ndarray,
    a_yaw: np.ndarray,
    b_centre: np.ndarray,
    b_half: np.ndarray,
    b_yaw: np.ndarray,
) -> np.ndarray:
    """Row by row, how far apart two oriented rectangles (centres (K, 2), half extents (K, 2), yaws (K,)) are at
    least: the widest gap along their four edge normals (separating axes). It is a lower bound of their distance,
    exact when an edge faces the other rectangle, and <= 0 when they overlap."""
    d = np.atleast_2d(b_centre) - np.atleast_2d(a_centre)
    a_half, b_half = np.atleast_2d(a_half), np.atleast_2d(b_half)
    axes_a, axes_b = _axes(a_yaw), _axes(b_yaw)
    gaps = []
    for axis in (*axes_a, *axes_b):
        ra = sum(a_half[:, i] * np.abs((axis * u).sum(1)) for i, u in enumerate(axes_a))
        rb = sum(b_half[:, i] * np.abs((axis * u).sum(1)) for i, u in enumerate(axes_b))
        gaps.append(np.abs((d * axis).sum(1)) - ra - rb)
    return np.max(gaps, axis=0)


def _axes(yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, 2) unit x and y axes of rectangles turned by `yaw` (K,)."""
    yaw = np.atleast_1d(np.asarray(yaw, dtype=np.float64))
    c, s = np.cos(yaw), np.sin(yaw)
    return np.column_stack([c, s]), np.column_stack([-s, c])


class PathClearance:
    """Distance queries from footprints to every point of the (densified) trajectory."""

    def __init__(self, xy: np.ndarray) -> None:
        seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        extra = [np.linspace(a, b, int(np.ceil(s / 0.5)) + 1)[1:] for a, b, s in zip(xy[:-1], xy[1:], seg)]
        self.points = np.concatenate([xy[:1], *extra]) if extra else xy
        self.arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.points, axis=0), axis=1))])
        self.tree = cKDTree(self.points)

    def is_clear(self, center: np.ndarray, half: np.ndarray, yaw: float, clearance: float) -> bool:
        idx = self.tree.query_ball_point(center, float(np.hypot(*half)) + clearance)
        if not idx:
            return True
        ex, ey = yaw_axes(yaw)
        rel = self.points[idx] - center
        dx = np.maximum(np.abs(rel @ ex) - half[0], 0.0)
        dy = np.maximum(np.abs(rel @ ey) - half[1], 0.0)
        return bool(np.all(dx * dx + dy * dy >= clearance * clearance))

    def only_within(self, center: np.ndarray, half: np.ndarray, yaw: float, start: float, end: float) -> bool:
        """True when every path point under the rectangle lies in the arc interval [start, end] (a tunnel
        roof may cover its own stretch of road, never another one)."""
        idx = self.tree.query_ball_point(center, float(np.hypot(*half)) + 1.0)
        if not idx:
            return True
        ex, ey = yaw_axes(yaw)
        rel = self.points[idx] - center
        under = (np.abs(rel @ ex) <= half[0] + 1.0) & (np.abs(rel @ ey) <= half[1] + 1.0)
        arc = self.arc[idx][under]
        return bool(np.all((arc >= start) & (arc <= end)))
