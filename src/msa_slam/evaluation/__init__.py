"""Evaluation: trajectory errors (evo), the paper's % improvement, memory and time accounting."""

from msa_slam.evaluation.resources import StageTimer, array_bytes, peak_rss_bytes
from msa_slam.evaluation.trajectory import TrajectoryError, align_se3, ate, improvement, rpe

__all__ = ["StageTimer", "TrajectoryError", "align_se3", "array_bytes", "ate", "improvement",
           "peak_rss_bytes", "rpe"]
