"""The pieces of one realistic scan: firing times, per-column rays of a moving sensor, and the imperfections
of real returns (lost dark or grazing returns, mixed pixels at depth edges, range-dependent noise).

Kept apart from the sensor model so each effect is a small function of arrays that can be tested alone.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from msa_slam.datasets.point_times import sweep_fraction

PoseAt = Callable[[np.ndarray], np.ndarray]  # times (k,) -> (k, 4, 4) world-from-sensor poses
REFERENCE_RANGE = 10.0  # m: return power is relative to a head-on white surface at this range
MAX_TAN_INCIDENCE = 20.0  # incidence noise stops growing beyond ~87 deg (such returns are mostly lost)


def fixed_pose(pose: np.ndarray) -> PoseAt:
    """A `PoseAt` for a sensor that does not move."""
    pose = np.asarray(pose, dtype=np.float64)
    return lambda times: np.broadcast_to(pose, (len(np.atleast_1d(times)), 4, 4))


def column_times(azimuth_steps: int, period: float) -> np.ndarray:
    """(A,) seconds from the sweep start at which each azimuth column (0, 2 pi / A, ...) fires: a clockwise
    sweep from the back, so the forward column fires at mid-sweep (as KITTI's HDL-64 and kiss-icp assume)."""
    azim = np.linspace(0.0, 2 * np.pi, azimuth_steps, endpoint=False)
    return period * sweep_fraction(np.cos(azim), np.sin(azim))


def sweep_rays(poses: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-frame origins and directions (B * A, 3) of sensor-frame rays `dirs` (B * A, 3, beam-major) cast
    from the pose of their column, `poses` (A, 4, 4): one array for a single batched cast."""
    local = dirs.reshape(-1, len(poses), 3)
    rot = poses[:, :3, :3]
    world = np.empty_like(local)
    for i in range(3):  # row by row: 3x faster than einsum or a stacked matmul of 3x3 blocks
        world[..., i] = local[..., 0] * rot[:, i, 0] + local[..., 1] * rot[:, i, 1] + local[..., 2] * rot[:, i, 2]
    origins = np.broadcast_to(poses[None, :, :3, 3], local.shape).reshape(-1, 3)
    return origins, world.reshape(-1, 3)


def lost_returns(
    reflectance: np.ndarray, cos_inc: np.ndarray, ranges: np.ndarray, floor: float, rng: np.random.Generator
) -> np.ndarray:
    """Mask of returns too weak to detect: received power ~ reflectance * cos(incidence) / range^2 (relative
    to REFERENCE_RANGE); a return at power `floor` is lost half the time, dark, grazing or far ones mostly."""
    power = reflectance * cos_inc * (REFERENCE_RANGE / ranges) ** 2
    return rng.random(len(ranges)) * (1.0 + (power / floor) ** 2) < 1.0


def mixed_pixels(
    ranges: np.ndarray,
    ray_idx: np.ndarray,
    grid: tuple[int, int],
    edge: float,
    prob: float,
    rng: np.random.Generator,
    hit_points: Callable[[np.ndarray], np.ndarray],
    normals: np.ndarray,
) -> np.ndarray:
    """`ranges` with mixed pixels: a return at a depth edge (its azimuth neighbour in the same beam more than
    `edge` metres nearer or farther, and that neighbour's hit more than `edge` off the plane of its own: another
    surface) straddles both surfaces, and with probability `prob` reports a range anywhere between them (the
    ghost points real sensors leave along depth edges). `hit_points(rows)` gives the hits (k, 3, any one frame) of
    the returns at `rows`, `normals` (P, 3) their surface normals. A surface seen at a grazing angle (a far stretch
    of road, a wall along the street) has neighbours metres apart in range but on one plane: no edge, its footprint
    sees one surface. The plane test is made only where the range jumps by more than `edge` (a few % of the
    returns; a smaller jump is no edge whatever the planes): the hits are asked for those rows alone."""
    flat = np.full(grid[0] * grid[1], -1)
    flat[ray_idx] = np.arange(len(ray_idx))
    index = flat.reshape(grid)
    jumps = []
    for shift in (1, -1):
        other = np.roll(index, shift, axis=1).ravel()[ray_idx]
        seen = other >= 0
        jump = np.zeros(len(ranges))
        jump[seen] = ranges[other[seen]] - ranges[seen]
        rows = np.flatnonzero(np.abs(jump) > edge)
        apart = np.einsum("ij,ij->i", normals[rows], hit_points(other[rows]) - hit_points(rows))
        jump[rows] *= np.abs(apart) > edge
        jumps.append(jump)
    jump = np.where(np.abs(jumps[0]) >= np.abs(jumps[1]), jumps[0], jumps[1])
    mixed = (np.abs(jump) > edge) & (rng.random(len(ranges)) < prob)
    return ranges + mixed * rng.random(len(ranges)) * jump


def range_sigma(base: float, per_metre: float, incidence: float, ranges: np.ndarray, cos_inc: np.ndarray) -> np.ndarray:
    """Range noise std per return: a constant, a part growing with range, and one growing with range and
    the tangent of the incidence angle (the beam's footprint spreads over depth on oblique surfaces)."""
    cos_inc = np.clip(cos_inc, 1.0 / np.hypot(1.0, MAX_TAN_INCIDENCE), 1.0)
    tan_inc = np.sqrt(1.0 - cos_inc**2) / cos_inc
    return np.sqrt(base**2 + (per_metre * ranges) ** 2 + (incidence * ranges * tan_inc) ** 2)
