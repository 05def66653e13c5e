"""Top-down trajectory figure with the selected keyframes marked."""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from msa_slam.io.atomic import atomic_path  # noqa: E402
from msa_slam.viz.layout import FRAME_H_IN, FRAME_W_IN, data_limits, fit_to_data, panel_grid  # noqa: E402


def plot_keyframes(
    poses: np.ndarray, keyframes: list[int], path: str | os.PathLike, title: str = "", flushed: list[int] | None = None
) -> None:
    """Write a PNG: the path in x-y (metres, equal aspect, the axes fitted to it and the figure shaped by it),
    keyframes as dots, end-of-stream flush keyframes apart, the legend below the axes."""
    xy = poses[:, :2, 3]
    (x0, x1), (y0, y1) = data_limits(xy)
    aspect = (x1 - x0) / (y1 - y0)
    width = min(panel_grid(1, aspect)[1], 8.0 * aspect, 9.0)
    fig, ax = plt.subplots(
        figsize=(width + FRAME_W_IN, width / aspect + FRAME_H_IN + 0.45), dpi=120, layout="constrained"
    )
    ax.plot(xy[:, 0], xy[:, 1], "-", color="0.6", lw=1, label=f"trajectory ({len(poses)} frames)")
    online = [k for k in keyframes if not flushed or k not in flushed]
    ax.scatter(xy[online, 0], xy[online, 1], s=12, c="tab:red", zorder=3, label=f"keyframes ({len(online)})")
    if flushed:
        ax.scatter(
            xy[flushed, 0],
            xy[flushed, 1],
            s=24,
            marker="x",
            c="tab:blue",
            zorder=4,
            label=f"end-of-stream flush ({len(flushed)})",
        )
    ax.scatter(xy[:1, 0], xy[:1, 1], s=60, marker="*", c="k", zorder=5, label="start")
    fit_to_data(ax, xy)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    fig.legend(loc="outside lower center", ncols=4, fontsize=8, frameon=False)  # below the axes, off the path
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
