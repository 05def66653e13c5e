"""Odometry: KISS-ICP or poses from a file, with a per-sequence on-disk cache."""

from msa_slam.odometry.cache import Odometry, OdometryCache, sequence_odometry
from msa_slam.odometry.kiss import KissOdometry, PosesFromFile

__all__ = ["KissOdometry", "Odometry", "OdometryCache", "PosesFromFile", "sequence_odometry"]
