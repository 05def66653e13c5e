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
from matplotlib.lines import Line2D  # noqa: E402

from msa_slam.viz.labels import counted  # noqa: E402
from msa_slam.viz.save import save_figure  # noqa: E402


@dataclass(frozen=True)
class TrajectoryPanel:
    """One panel: an estimate's xy (K, 2) with per-point error (m), and loops as index pairs into it (None: an
    estimate loops play no part in, such as the odometry, whose title then counts none)."""

    title: str
    xy: np.ndarray
    errors: np.ndarray
    loops: Sequence[tuple[int, int]] | None = None
    false_loops: Sequence[tuple[int, int]] = ()


TRUE_LOOP, FALSE_LOOP = "tab:orange", "tab:red"  # loop colours kept off the error colour map (viridis)


def _draw(ax, gt_xy: np.ndarray, panel: TrajectoryPanel, norm: Normalize, cmap: str):
    ax.plot(gt_xy[:, 0], gt_xy[:, 1], color="0.8", lw=3.0, zorder=1)
    segments = np.stack([panel.xy[:-1], panel.xy[1:]], axis=1)
    lines = LineCollection(segments, cmap=cmap, norm=norm, lw=1.2, zorder=2)
    lines.set_array(0.5 * (panel.errors[:-1] + panel.errors[1:]))
    ax.add_collection(lines)
    ax.scatter(panel.xy[:, 0], panel.xy[:, 1], c=panel.errors, cmap=cmap, norm=norm, s=5, zorder=3)
    # Loop edges over everything, with hollow end markers: a loop between nearby keyframes is a short edge
    # that a line alone would hide.
    for pairs, colour, marker in ((panel.loops or (), TRUE_LOOP, "o"), (panel.false_loops, FALSE_LOOP, "X")):
        for a, b in pairs:
            ax.plot(*panel.xy[[a, b]].T, color=colour, lw=1.2, zorder=4, marker=marker, ms=3.5, mfc="none", mew=0.8)
    counts = "" if panel.loops is None else (f", {counted(len(panel.loops), 'loop')}" + (
        f", {len(panel.false_loops)} false" if len(panel.false_loops) else ""))
    ax.set_title(f"{panel.title}\n{counted(len(panel.xy), 'keyframe')}{counts}", fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]", fontsize=8)
    ax.set_ylabel("y [m]", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    return lines


def _legend_handles(panels: Sequence[TrajectoryPanel], cmap: str) -> list[Line2D]:
    handles = [Line2D([], [], color="0.8", lw=3.0, label="ground truth"),
               Line2D([], [], color=plt.get_cmap(cmap)(0.5), marker="o", ms=3, lw=1.2,
                      label="keyframes, SE(3)-aligned to ground truth (colour: ATE)")]
    if any(p.loops for p in panels):
        handles.append(Line2D([], [], color=TRUE_LOOP, marker="o", mfc="none", lw=1.4, label="loop (true)"))
    if any(len(p.false_loops) for p in panels):
        handles.append(Line2D([], [], color=FALSE_LOOP, marker="X", mfc="none", lw=1.4, label="loop (false)"))
    return handles


def plot_trajectories(path: str | Path, gt_xy: np.ndarray, panels: Sequence[TrajectoryPanel],
                      title: str = "", columns: int | None = None, cmap: str = "viridis") -> Path:
    """Write panels side by side (shared colour scale of the error in metres) over the ground truth, with
    one legend for all panels below them."""
    columns = columns or len(panels)
    rows = int(np.ceil(len(panels) / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(3.6 * columns + 1.2, 3.6 * rows + 0.9), dpi=130, squeeze=False,
                             layout="constrained")
    top = max(float(np.max(p.errors)) for p in panels) if panels else 1.0
    norm = Normalize(0.0, max(top, 1e-6))
    try:
        lines = None
        for ax, panel in zip(axes.ravel(), panels):
            lines = _draw(ax, np.asarray(gt_xy), panel, norm, cmap)
        for ax in axes.ravel()[len(panels):]:
            ax.axis("off")
        if lines is not None:
            fig.colorbar(lines, ax=axes.ravel().tolist(), shrink=0.8, label="ATE per keyframe [m]")
        fig.legend(handles=_legend_handles(panels, cmap), loc="outside lower center", ncols=4, fontsize=8,
                   frameon=False)
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
            ax.set_ylabel(metric, fontsize=8)  # names carry their unit, e.g. "ATE translation [m]"
            ax.tick_params(axis="y", labelsize=7)
            ax.grid(axis="y", alpha=0.3)
            if len(groups) > 1:  # above the axes: inside, it would cover bars
                ax.legend(fontsize=7, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncols=len(groups),
                          frameon=False)
        if title:
            fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        return save_figure(fig, path)
    finally:
        plt.close(fig)
