"""Evaluation: trajectory errors (evo), the paper's % improvement, memory and time accounting."""

from msa_slam.evaluation.display import NA, fmt, notes
from msa_slam.evaluation.resources import PROCESS_RSS_LABEL, StageTimer, array_bytes, peak_rss_bytes
from msa_slam.evaluation.summary import TrajectoryEvaluation, evaluate_trajectories, improvement_pct
from msa_slam.evaluation.trajectory import (ATE_ALIGNMENT, AlignmentError, TrajectoryError, align_se3,
                                            alignment_warnings, ate, improvement, rpe)

__all__ = ["ATE_ALIGNMENT", "AlignmentError", "NA", "PROCESS_RSS_LABEL", "StageTimer", "TrajectoryError",
           "TrajectoryEvaluation", "align_se3", "alignment_warnings", "array_bytes", "ate",
           "evaluate_trajectories", "fmt", "improvement", "improvement_pct", "notes", "peak_rss_bytes", "rpe"]
