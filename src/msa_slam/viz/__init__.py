"""Figures (matplotlib, Agg): trajectories coloured by error with keyframes and loops, metric bars, and the
online / experiment figures (memory over time, per-step times, ATE differences, parameter sweeps)."""

from msa_slam.viz.experiment_figures import plot_ate_difference, plot_memory, plot_step_times, plot_sweeps
from msa_slam.viz.save import save_figure
from msa_slam.viz.trajectories import TrajectoryPanel, plot_metric_bars, plot_trajectories

__all__ = ["TrajectoryPanel", "plot_ate_difference", "plot_memory", "plot_metric_bars", "plot_step_times",
           "plot_sweeps", "plot_trajectories", "save_figure"]
