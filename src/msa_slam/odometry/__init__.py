"""Odometry: KISS-ICP, poses from a file, noisy ground truth or replayed poses, with a per-sequence cache."""

from msa_slam.odometry.cache import Odometry, OdometryCache, sequence_odometry
from msa_slam.odometry.kiss import KissOdometry, PosesFromFile
from msa_slam.odometry.noisy import NoisyOdometry, ReplayedOdometry

__all__ = [
    "KissOdometry",
    "NoisyOdometry",
    "Odometry",
    "OdometryCache",
    "PosesFromFile",
    "ReplayedOdometry",
    "sequence_odometry",
]
