"""Sensor trajectories for the simulator: real KITTI ground truth, procedural paths and user files.

KITTI paths (Geiger et al., CVPR 2012; CC BY-NC-SA 3.0) come from the package's compact data files
(see `kitti_data`). Procedural paths are generated at 10 Hz: a figure-eight, a city tour on a street grid
with revisits, a short drive that comes back along its street in the other lane (reverse-revisit), and a slow
handheld-like campus walk (about 0.1 m per frame, like Newer College).
Any other path comes from a pose file (KITTI 12 numbers a line or TUM `t x y z qx qy qz qw`), see
`read_trajectory`. `Trajectory.pose_at` interpolates the full-rate poses for motion distortion.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from msa_slam.datasets.sequences import read_kitti_calibration, read_times
from msa_slam.errors import InputError
from msa_slam.evaluation.sanity import steps_along_z
from msa_slam.io.poses import read_poses
from msa_slam.sim.kitti_data import DATA_DIR, KITTI_SEQUENCES, cam0_to_lidar

FRAME_RATE_HZ = 10.0
MIN_POSES = 2
PRINTED_ROTATION_TOLERANCE = 1e-3  # KITTI files print rotations with few digits: orthonormalised after reading


@dataclass(frozen=True)
class Trajectory:
    """World-from-LiDAR poses (N, 4, 4), timestamps (N,), the platform kind ("car" or "walk") and the
    sensor's height above the ground (KITTI's Velodyne: 1.73 m)."""

    name: str
    poses: np.ndarray
    times: np.ndarray
    platform: str
    sensor_height: float = 1.73

    def __len__(self) -> int:
        return len(self.poses)

    def pose_at(self, times: np.ndarray) -> np.ndarray:
        """(k, 4, 4) world-from-sensor poses at `times` (s, the trajectory's clock), interpolated between the
        two nearest poses (rotation by slerp, translation linearly) and extrapolated at constant velocity
        from the first/last segment outside the trajectory (a sweep that starts before the first pose)."""
        return interpolate_poses(self.poses, self.times, np.asarray(times, dtype=np.float64))


def interpolate_poses(poses: np.ndarray, stamps: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Poses of an (N, 4, 4) stack stamped `stamps` (N >= 2, increasing) at `times`; see Trajectory.pose_at."""
    times = np.atleast_1d(times)
    seg = np.clip(np.searchsorted(stamps, times, side="right") - 1, 0, len(stamps) - 2)
    t0, t1 = stamps[seg], stamps[seg + 1]
    s = (times - t0) / (t1 - t0)
    a, b = poses[seg], poses[seg + 1]
    delta = Rotation.from_matrix(np.einsum("kji,kjl->kil", a[:, :3, :3], b[:, :3, :3])).as_rotvec()
    out = np.tile(np.eye(4), (len(times), 1, 1))
    out[:, :3, :3] = np.einsum("kij,kjl->kil", a[:, :3, :3], Rotation.from_rotvec(delta * s[:, None]).as_matrix())
    out[:, :3, 3] = a[:, :3, 3] + s[:, None] * (b[:, :3, 3] - a[:, :3, 3])
    return out


def _poses(positions: np.ndarray, rotations: Rotation) -> np.ndarray:
    poses = np.tile(np.eye(4), (len(positions), 1, 1))
    poses[:, :3, :3] = rotations.as_matrix()
    poses[:, :3, 3] = positions
    return poses


def _kitti(seq: str) -> Trajectory:
    data = np.load(DATA_DIR / f"kitti_{seq}.npz")
    rot = Rotation.from_quat(data["quaternions"].astype(np.float64))
    poses = _poses(data["translations"].astype(np.float64), rot)
    return Trajectory(f"kitti-{seq}", poses, data["times"].astype(np.float64), "car")


def _resample(xy: np.ndarray, step: np.ndarray | float) -> np.ndarray:
    """Points along the polyline `xy` at arc-length spacing `step`, or at the arc-length stations `step`."""
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    stations = step if isinstance(step, np.ndarray) else np.arange(0.0, arc[-1], step)
    return np.column_stack([np.interp(stations, arc, xy[:, k]) for k in range(2)])


def _planar(
    name: str, xy: np.ndarray, height: np.ndarray, platform: str, roll_pitch: np.ndarray | None = None
) -> Trajectory:
    """Poses facing along the path (x forward, z up), from positions sampled at 10 Hz."""
    heading = np.gradient(xy, axis=0)
    yaw = np.unwrap(np.arctan2(heading[:, 1], heading[:, 0]))
    euler = np.zeros((len(xy), 3))
    euler[:, 2] = yaw
    if roll_pitch is not None:
        euler[:, :2] = roll_pitch
    rot = Rotation.from_euler("xyz", euler)  # fixed axes: R = Rz(yaw) Ry(pitch) Rx(roll)
    positions = np.column_stack([xy, height])
    times = np.arange(len(xy)) / FRAME_RATE_HZ
    return Trajectory(name, _poses(positions, rot), times, platform)


START_ACCEL = 2.5  # m/s^2: procedural vehicles pull away from rest, as a car does
START_SPEED = 0.5  # m/s at the first frame


def _speed_profile(
    length: float, cruise: float, curvature_slow: Callable[[np.ndarray], np.ndarray] = np.ones_like
) -> np.ndarray:
    """Arc-length stations of a vehicle starting from rest (START_ACCEL) up to `cruise` m/frame, slowing
    where `curvature_slow` says. A standing start lets odometry's constant-velocity prior (zero at the
    first scan) follow; a path that starts at full speed can leave KISS-ICP stuck at its start."""
    stations = [0.0]
    while stations[-1] < length:
        s = stations[-1]
        pulling_away = np.sqrt(START_SPEED**2 + 2.0 * START_ACCEL * s) / FRAME_RATE_HZ
        stations.append(s + min(pulling_away, cruise * float(curvature_slow(np.array([s]))[0])))
    return np.array(stations[:-1])


FIGURE_EIGHT_FRAMES = 427  # its duration; the frame count the tests' sequences are built from


def figure_eight() -> Trajectory:
    """A lemniscate of Bernoulli (70 m half-width) driven for 42.7 s (427 frames), from rest up to ~1 m per
    frame over the first 20 m and about 1.1 times round: revisits at the crossing (perpendicular headings)
    and where the path closes on its start."""
    t = np.linspace(0.0, 2.3 * np.pi, 4000)
    a = 70.0
    den = 1.0 + np.sin(t) ** 2
    xy = np.column_stack([a * np.cos(t) / den, a * np.sin(t) * np.cos(t) / den])
    length = float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())
    xy = _resample(xy, _speed_profile(length, 1.0)[:FIGURE_EIGHT_FRAMES])
    return _planar("figure-eight", xy, np.zeros(len(xy)), "car")


def _rounded_polyline(corners: np.ndarray, radius: float) -> np.ndarray:
    """A polyline through grid `corners` with each interior corner replaced by a circular arc."""
    pts = [corners[0]]
    for k in range(1, len(corners) - 1):
        prev, cur, nxt = corners[k - 1], corners[k], corners[k + 1]
        d_in = (cur - prev) / np.linalg.norm(cur - prev)
        d_out = (nxt - cur) / np.linalg.norm(nxt - cur)
        if abs(d_in[0] * d_out[1] - d_in[1] * d_out[0]) < 1e-9:  # straight through
            pts.append(cur)
            continue
        a0, a1 = cur - d_in * radius, cur + d_out * radius
        s = np.linspace(0.0, 1.0, 12)[:, None]
        pts.extend((1 - s) ** 2 * a0 + 2 * s * (1 - s) * cur + s**2 * a1)  # quadratic Bezier arc
    pts.append(corners[-1])
    return np.array(pts)


def _street_drive(name: str, route: np.ndarray) -> Trajectory:
    """A car driving the street corners `route` (m), turning on 12 m arcs, ~1.1 m per frame slowing to ~0.5 m
    in turns (braking over ~20 m before them)."""
    dense = _resample(_rounded_polyline(route, 12.0), 0.2)
    turn = np.abs(np.gradient(np.unwrap(np.arctan2(*np.gradient(dense, axis=0).T[::-1]))))
    arc = np.arange(len(dense)) * 0.2
    slow_zone = (np.convolve(turn > 0.01, np.ones(150), mode="same") > 0).astype(float)
    slow_zone = np.convolve(slow_zone, np.ones(100) / 100, mode="same")  # brake over ~20 m (~2.5 m/s^2)

    def factor(s: np.ndarray) -> np.ndarray:
        return 1.0 - 0.55 * np.interp(s, arc, slow_zone)

    stations = _speed_profile(arc[-1], 1.1, factor)
    xy = np.column_stack([np.interp(stations, arc, dense[:, k]) for k in range(2)])
    return _planar(name, xy, np.zeros(len(xy)), "car")


def city_tour() -> Trajectory:
    """A drive on a 90 m street grid that loops around blocks and comes back along earlier streets
    (several revisits, some in the opposite direction), ~1.1 m per frame slowing to ~0.5 m in turns."""
    grid = 90.0
    route = (
        np.array(
            [
                (0, 0),
                (3, 0),
                (3, 2),
                (1, 2),
                (1, 0),
                (1, -1),
                (4, -1),
                (4, 1),
                (3, 1),
                (3, 0),
                (2, 0),
                (2, 2),
                (0, 2),
                (0, 0),
                (1, 0),
            ],
            dtype=float,
        )
        * grid
    )
    return _street_drive("city-tour", route)


REVERSE_LANE_OFFSET = 2.5  # m: the way back runs in the other lane, inside the 3 m radius that counts a revisit


def reverse_revisit() -> Trajectory:
    """Out along a street (100 m), round a 40 m block on its left, and back down the same street in the other
    lane (REVERSE_LANE_OFFSET to the side, facing the other way) past the start: ~50 m revisited in the opposite
    direction, 155-260 m of path after the first pass, in 432 frames (43 s, 269 m). The revisit a descriptor
    must recognise from behind and registration must align across a half turn, short enough for the tests."""
    lane = REVERSE_LANE_OFFSET
    route = np.array([(0, 0), (100, 0), (100, 40), (60, 40), (60, lane), (-10, lane)], dtype=float)
    return _street_drive("reverse-revisit", route)


def campus_walk() -> Trajectory:
    """A handheld walk (~0.1 m per frame, 1.2 m above ground with step bob and sway) around two
    quads of a campus, passing the first quad's paths twice."""
    route = np.array(
        [(0, 0), (40, 0), (40, 30), (0, 30), (0, 0), (-35, 0), (-35, -25), (0, -25), (0, 0), (40, 0), (40, 12)],
        dtype=float,
    )
    xy = _resample(_rounded_polyline(route, 4.0), 0.1)
    n = len(xy)
    steps = np.arange(n) * 2 * np.pi / 6.0  # about one step every 0.6 s
    height = 1.2 + 0.02 * np.sin(2 * steps)
    roll_pitch = np.column_stack([np.radians(1.5) * np.sin(steps), np.radians(1.0) * np.sin(2 * steps + 0.4)])
    traj = _planar("campus-walk", xy, height, "walk", roll_pitch)
    return replace(traj, sensor_height=1.2)


_PROCEDURAL: dict[str, Callable[[], Trajectory]] = {
    "figure-eight": figure_eight,
    "city-tour": city_tour,
    "reverse-revisit": reverse_revisit,
    "campus-walk": campus_walk,
}
TRAJECTORY_NAMES: tuple[str, ...] = tuple(f"kitti-{s}" for s in KITTI_SEQUENCES) + tuple(_PROCEDURAL)


def _orthonormal(rot: np.ndarray) -> np.ndarray:
    """The nearest rotations (SVD) of nearly rigid (N, 3, 3) matrices: printed files round their digits."""
    u, _, vt = np.linalg.svd(rot)
    return u @ vt


def read_trajectory(
    path: str | Path, fmt: str = "auto", times_file: str | Path | None = None, calib_file: str | Path | None = None
) -> Trajectory:
    """A trajectory from a pose file: KITTI (12 numbers a line, times from `times_file` or 10 Hz) or TUM
    (`t x y z qx qy qz qw`; its own times). With `calib_file` (a KITTI calib.txt with a `Tr:` line) the poses
    are cam0 poses, converted to the LiDAR frame as inv(Tr) P Tr. Positions are shifted so the first pose
    sits at the origin (Embree casts in float32); the poses must be LiDAR-like (x forward, z up: the world
    is built with its ground below each pose), so a path driven along the sensor's z axis is refused.
    Every problem is one InputError naming the file and line."""
    path = Path(path)
    poses, stamps = read_poses(path, fmt, rotation_tolerance=PRINTED_ROTATION_TOLERANCE)
    if len(poses) < MIN_POSES:
        raise InputError(f"{path}: {len(poses)} pose(s); a trajectory needs at least {MIN_POSES}")
    poses[:, :3, :3] = _orthonormal(poses[:, :3, :3])
    if stamps is not None:
        if times_file is not None:
            raise InputError(f"{times_file}: a TUM trajectory ({path}) carries its own times; give no times file")
        times = stamps
    elif times_file is not None:
        times = read_times(Path(times_file))
        if len(times) != len(poses):
            raise InputError(f"{times_file}: {len(times)} times for the {len(poses)} poses of {path}")
    else:
        times = np.arange(len(poses)) / FRAME_RATE_HZ
    if calib_file is not None:
        poses = cam0_to_lidar(poses, read_kitti_calibration(Path(calib_file)))
    along_z, moving = steps_along_z(poses)
    if len(along_z) > 0.5 * max(1, moving):
        raise InputError(
            f"{path}: the sensor moves along its z axis on {len(along_z)} of {moving} moving steps "
            f"(from pose {along_z[0] + 1}; camera poses, z forward?) while a LiDAR frame has x forward, "
            "z up; give --calib with the KITTI calib.txt (Tr line)"
        )
    poses[:, :3, 3] -= poses[0, :3, 3]
    return Trajectory(path.stem, poses, times - times[0], "car")


def load_trajectory(name: str) -> Trajectory:
    """The whole named trajectory; unknown names raise InputError listing the known ones."""
    if name in _PROCEDURAL:
        return _PROCEDURAL[name]()
    if name.startswith("kitti-") and name[6:] in KITTI_SEQUENCES:
        return _kitti(name[6:])
    raise InputError(f"unknown trajectory {name!r}; choose one of {', '.join(TRAJECTORY_NAMES)}")


def frame_indices(
    total: int, start: int = 0, end: int | None = None, stride: int = 1, name: str = "trajectory"
) -> np.ndarray:
    """Indices start, start+stride, ... < end of a `total`-frame trajectory, validated."""
    end = total if end is None else end
    if stride < 1:
        raise InputError(f"{name}: stride must be >= 1, got {stride}")
    if not 0 <= start < total:
        raise InputError(f"{name}: start {start} outside 0..{total - 1}")
    if not start < end <= total:
        raise InputError(f"{name}: end {end} must be in {start + 1}..{total} (the trajectory has {total} frames)")
    return np.arange(start, end, stride)
