"""Comparing poses in tests."""

from __future__ import annotations

import numpy as np


def pose_error(estimate: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation angle (degrees) of reference^-1 estimate."""
    delta = np.linalg.inv(reference) @ estimate
    angle = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(delta[:3, 3])), float(angle)
