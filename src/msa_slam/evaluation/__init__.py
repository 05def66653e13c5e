"""Evaluation: trajectory errors (evo), the paper's % improvement, memory and time accounting."""

from msa_slam._lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(["NA", "fmt", "notes"], "display"),
    **dict.fromkeys(
        [
            "KITTI_LENGTHS_M",
            "distance_rpe",
            "evaluate_full_rate",
            "full_rate_poses",
            "segment_error_motions",
            "segment_errors",
        ],
        "full_rate",
    ),
    **dict.fromkeys(["PROCESS_RSS_LABEL", "StageTimer", "array_bytes", "peak_rss_bytes"], "resources"),
    **dict.fromkeys(["TrajectoryEvaluation", "evaluate_trajectories", "improvement_pct"], "summary"),
    **dict.fromkeys(
        [
            "ATE_ALIGNMENT",
            "AlignmentError",
            "TrajectoryError",
            "align_se3",
            "alignment_warnings",
            "ate",
            "improvement",
            "rpe",
        ],
        "trajectory",
    ),
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
