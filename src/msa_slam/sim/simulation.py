"""A resolved simulation: the selected frames of the full-rate trajectory, the world built around them and the
bound sensor; scans are cast on demand (`Simulation.scan`) or iterated in memory (`iter_frames`)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from msa_slam.sim.config import SimConfig
from msa_slam.sim.coverage import check_reaches_ground, warn_short_range
from msa_slam.sim.level import gravity_up
from msa_slam.sim.realism import REALISM, Realism
from msa_slam.sim.sensors import Lidar, LidarModel, get_sensor
from msa_slam.sim.trajectories import Trajectory, frame_indices
from msa_slam.sim.world import World, build_world


@dataclass(frozen=True)
class SimFrame:
    """One simulated scan: output index, time (s from the first frame), points, ground-truth pose."""

    index: int
    time: float
    points: np.ndarray
    gt_pose: np.ndarray


@dataclass
class Simulation:
    """A resolved config: the selected frames, the full-rate trajectory they come from, the world built
    around them and the bound sensor."""

    config: SimConfig
    frames: np.ndarray  # source-trajectory indices of the output frames
    trajectory: Trajectory  # full rate: motion distortion interpolates between its poses
    world: World
    lidar: Lidar
    realism: Realism

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def poses(self) -> np.ndarray:
        return self.trajectory.poses[self.frames]

    @property
    def times(self) -> np.ndarray:
        """Output frame times, seconds from the first output frame."""
        return self.trajectory.times[self.frames] - self.trajectory.times[self.frames[0]]

    def scan(self, k: int, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """(P, 4) float32 scan of output frame k and its per-point times (float64 s from the sweep start;
        None for a clean preset, whose sensor stands still); noise is seeded by (seed, source frame) unless
        `rng` is given (a live source drawing each lap's noise apart)."""
        frame = int(self.frames[k])
        rng = np.random.default_rng([self.config.seed, frame]) if rng is None else rng
        if self.realism.is_clean:
            return self.lidar.scan(self.trajectory.poses[frame], rng, float(self.trajectory.times[frame])), None
        return self.lidar.sweep(self.trajectory.pose_at, float(self.trajectory.times[frame]), rng)


def prepare(config: SimConfig) -> Simulation:
    """Load the trajectory, select frames, check the sensor (before the long work) and build the world around
    the whole selected range (unstrided, so every stride of the same range sees the same world); an upright
    world stands along the gravity of the whole trajectory, so a part of it is built as the whole is."""
    traj = config.load_trajectory()
    frames = frame_indices(len(traj), config.start, config.end, config.stride, config.label)
    model: LidarModel = get_sensor(
        config.sensor,
        azimuth_steps=config.azimuth_steps,
        max_range=config.max_range,
        range_noise=config.range_noise,
        dropout=config.dropout,
    )
    check_reaches_ground(model, traj.sensor_height)
    warn_short_range(config)
    span = traj.poses[frames[0] : frames[-1] + 1]
    style = config.style or ("campus" if traj.platform == "walk" else "city")
    realism = REALISM[config.realism]
    # a vehicle's gravity is read from its drive (sim.level); a walker's sway is no vehicle's roll, and the
    # procedural walk is level as made
    up = None
    if realism.world.upright:
        up = gravity_up(traj.poses, traj.times) if traj.platform == "car" else np.array([0.0, 0.0, 1.0])
    times = traj.times[frames[0] : frames[-1] + 1]
    world = build_world(span, style, config.seed, traj.sensor_height, realism.world, up, times)
    return Simulation(config, frames, traj, world, Lidar(model, world, realism.sensor, config.seed), realism)


def iter_frames(config: SimConfig, with_intensity: bool = False) -> Iterator[SimFrame]:
    """Simulate in memory: yields SimFrame(index, time, points (P,3) or (P,4) float32, gt_pose)."""
    sim = prepare(config)
    for k in range(len(sim)):
        pts, _ = sim.scan(k)
        yield SimFrame(k, float(sim.times[k]), pts if with_intensity else pts[:, :3].copy(), sim.poses[k])
