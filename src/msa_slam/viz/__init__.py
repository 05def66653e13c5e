"""Figures (matplotlib, Agg): trajectories coloured by error with keyframes and loops, metric bars."""

from msa_slam.viz.save import save_figure
from msa_slam.viz.trajectories import TrajectoryPanel, plot_metric_bars, plot_trajectories

__all__ = ["TrajectoryPanel", "plot_metric_bars", "plot_trajectories", "save_figure"]
