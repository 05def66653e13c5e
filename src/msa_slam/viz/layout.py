"""Map panels fitted to the data: world axes at equal aspect, limits on the data's extent, and a panel grid
chosen by that extent's aspect. A long thin route (KITTI-06 is 457 x 22 m) then fills wide panels stacked in one
column instead of a square axis that leaves most of each panel white."""

from __future__ import annotations

import math

import numpy as np

PAD = 0.04  # of each side's span on either side: markers on the edge stay whole
MIN_SPAN = 0.05  # a side spans at least this fraction of the other: a straight route still gets a visible strip
MAX_WIDTH_IN, MAX_HEIGHT_IN = 13.0, 15.0  # the grid of panels fits in this (inches)
FRAME_W_IN, FRAME_H_IN = 0.9, 0.7  # what a panel needs beside its axes: y ticks and label; title, x ticks, label


def data_limits(xy: np.ndarray) -> tuple[tuple[float, float], tuple[float, float]]:
    """x and y limits (metres) around the finite points of `xy` (N, 2), each side padded by PAD of its span."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    xy = xy[np.isfinite(xy).all(axis=1)]
    if not len(xy):
        return (-1.0, 1.0), (-1.0, 1.0)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    span = np.maximum(hi - lo, max(1.0, MIN_SPAN * float((hi - lo).max())))
    centre, half = (lo + hi) / 2, span * (0.5 + PAD)
    return (centre[0] - half[0], centre[0] + half[0]), (centre[1] - half[1], centre[1] + half[1])


def fit_to_data(ax, xy: np.ndarray) -> float:
    """Limit `ax` to the extent of `xy` at equal aspect (the axes box takes the data's shape, not the reverse);
    return that extent's width / height."""
    (x0, x1), (y0, y1) = data_limits(xy)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")
    return (x1 - x0) / (y1 - y0)


def panel_grid(n: int, aspect: float) -> tuple[int, float]:
    """(columns, axes width in inches) of the grid of `n` panels of width / height `aspect` whose axes are
    largest within MAX_WIDTH_IN x MAX_HEIGHT_IN: one column of wide strips for a long thin route, a squarer grid
    for a compact one."""
    best = (1, 0.0)
    for columns in range(1, max(n, 1) + 1):
        rows = math.ceil(n / columns)
        width = min(MAX_WIDTH_IN / columns - FRAME_W_IN, (MAX_HEIGHT_IN / rows - FRAME_H_IN) * aspect)
        if width > best[1] + 1e-9:
            best = (columns, width)
    return best[0], max(best[1], 1.0)
