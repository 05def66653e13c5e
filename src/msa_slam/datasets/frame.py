"""What every source yields: one scan with its index, time and (when known) ground-truth pose."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Frame:
    """A scan: `points` (P, 3) in the sensor frame, `gt_pose` world-from-LiDAR (4, 4) or None, and
    `timestamps` (P,) seconds from the sweep start of each point when the source knows them (for deskewing)."""

    index: int
    time: float
    points: np.ndarray
    gt_pose: np.ndarray | None = None
    timestamps: np.ndarray | None = None
