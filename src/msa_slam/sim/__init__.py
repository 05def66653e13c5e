"""LiDAR simulator: procedural worlds around real (KITTI), procedural or user-file trajectories, Embree ray
casting, realism presets, and cached sequences in the KITTI odometry layout (the project's embedded default data)."""

from msa_slam.sim.config import SimConfig, make_config
from msa_slam.sim.realism import REALISM, Realism, get_realism
from msa_slam.sim.sensors import SENSORS, Lidar, LidarModel, get_sensor
from msa_slam.sim.sequence import DEFAULT_CONFIGS, default_sequence, simulate_sequence
from msa_slam.sim.simulation import SimFrame, Simulation, iter_frames, prepare
from msa_slam.sim.trajectories import TRAJECTORY_NAMES, Trajectory, load_trajectory, read_trajectory
from msa_slam.sim.world import World, build_world

__all__ = [
    "DEFAULT_CONFIGS",
    "REALISM",
    "SENSORS",
    "TRAJECTORY_NAMES",
    "Lidar",
    "LidarModel",
    "Realism",
    "SimConfig",
    "SimFrame",
    "Simulation",
    "Trajectory",
    "World",
    "build_world",
    "default_sequence",
    "get_realism",
    "get_sensor",
    "iter_frames",
    "load_trajectory",
    "make_config",
    "prepare",
    "read_trajectory",
    "simulate_sequence",
]
