"""Trajectory figures: ground truth, odometry and optimised keyframes coloured by their error, loops marked.

Estimates are drawn after the same SE(3) alignment the ATE uses, so colour and position tell one story
(like the paper's Fig. 6, which colours trajectories by error).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import Normalize  # noqa: E402

from msa_slam.viz.save import save_figure  # noqa: E402


@dataclass(frozen=True)
class TrajectoryPanel:
    """One panel: an estimate's xy (K, 2) with per-point error (m), and loops as index pairs into it."""

    title: str
    xy: np.ndarray
    errors: np.ndarray
    loops: Sequence[tuple[int, int]] = ()
    false_loops: Sequence[tuple[int, int]] = ()


def _draw(ax, gt_xy: np.ndarray, panel: TrajectoryPanel, norm: Normalize, cmap: str):
    ax.plot(gt_xy[:, 0], gt_xy[:, 1], color="0.75", lw=2.5, label="ground truth", zorder=1)
    segments = np.stack([panel.xy[:-1], panel.xy[1:]], axis=1)
    lines = LineCollection(segments, cmap=cmap, norm=norm, lw=1.2, zorder=2)
    lines.set_array(0.5 * (panel.errors[:-1] + panel.errors[1:]))
    ax.add_collection(lines)
    ax.scatter(panel.xy[:, 0], panel.xy[:, 1], c=panel.errors, cmap=cmap, norm=norm, s=4, zorder=3,
               label=f"keyframes ({len(panel.xy)})")
    for pairs, colour, name in ((panel.loops, "tab:green", "loops"), (panel.false_loops, "tab:red", "false loops")):
        for n, (a, b) in enumerate(pairs):
            ax.plot(*panel.xy[[a, b]].T, color=colour, lw=0.8, zorder=4,
                    label=f"{name} ({len(pairs)})" if n == 0 else None)
    ax.set_title(panel.title, fontsize=9)
    ax.set_aspect("equal", adjustable="datalim")
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    return lines


def plot_trajectories(path: str | Path, gt_xy: np.ndarray, panels: Sequence[TrajectoryPanel],
                      title: str = "", columns: int | None = None, cmap: str = "viridis") -> Path:
    """Write panels side by side (shared colour scale of the error in metres) over the ground truth."""
    columns = columns or len(panels)
    rows = int(np.ceil(len(panels) / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 4.0 * rows), dpi=130, squeeze=False)
    top = max(float(np.max(p.errors)) for p in panels) if panels else 1.0
    norm = Normalize(0.0, max(top, 1e-6))
    try:
        lines = None
        for ax, panel in zip(axes.ravel(), panels):
            lines = _draw(ax, np.asarray(gt_xy), panel, norm, cmap)
        axes.ravel()[0].legend(fontsize=6, loc="best")
        for ax in axes.ravel()[len(panels):]:
            ax.axis("off")
        if lines is not None:
            fig.colorbar(lines, ax=axes.ravel().tolist(), shrink=0.8, label="ATE per keyframe [m]")
        if title:
            fig.suptitle(title, fontsize=10)
        return save_figure(fig, path)
    finally:
        plt.close(fig)


def plot_metric_bars(path: str | Path, labels: Sequence[str], series: Mapping[str, Mapping[str, Sequence[float]]],
                     title: str = "") -> Path:
    """One subplot per metric (`series[metric][legend] = values per label`), grouped bars per label."""
    fig, axes = plt.subplots(1, len(series), figsize=(4.0 * len(series), 3.6), dpi=130, squeeze=False)
    x = np.arange(len(labels))
    try:
        for ax, (metric, groups) in zip(axes[0], series.items()):
            width = 0.8 / max(1, len(groups))
            for k, (legend, values) in enumerate(groups.items()):
                ax.bar(x + (k - (len(groups) - 1) / 2) * width, values, width, label=legend)
            ax.set_xticks(x, labels, rotation=35, ha="right", fontsize=7)
            ax.set_title(metric, fontsize=9)
            ax.tick_params(axis="y", labelsize=7)
            ax.grid(axis="y", alpha=0.3)
            if len(groups) > 1:
                ax.legend(fontsize=7, loc="lower right")
        if title:
            fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        return save_figure(fig, path)
    finally:
        plt.close(fig)
