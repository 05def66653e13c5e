"""Figures (matplotlib, Agg): trajectories coloured by error with keyframes and loops, the methods' metrics, and the
online / experiment figures (memory over time, per-step times, ATE differences, parameter sweeps)."""

from msa_slam._lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(["plot_ate_difference", "plot_memory", "plot_step_times", "plot_sweeps"], "experiment_figures"),
    **dict.fromkeys(["MethodMetric", "plot_method_metrics"], "method_metrics"),
    "save_figure": "save",
    **dict.fromkeys(["TrajectoryPanel", "plot_trajectories"], "trajectories"),
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
