"""Figures of `msa-slam reproduce`: the paper's Fig. 5 (box plots of every method's deviation from all samples
over the Table I runs) and its memory figure drawn against distance, with the all-samples extrapolation and the
paper's 128 GB machine marked."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from msa_slam.viz.save import save_figure  # noqa: E402


def plot_boxes(
    path: str | Path,
    panels: Mapping[str, Mapping[str, Sequence[float]]],
    title: str = "",
    zero_line: Sequence[str] = (),
) -> Path:
    """One box plot per panel (title with its unit -> method -> values), side by side; panels named in
    `zero_line` get a line at 0 (a deviation's "no change"). A method without values is left out of its panel."""
    names = list(panels)
    fig, axes = plt.subplots(1, len(names), figsize=(3.3 * len(names) + 0.5, 3.9), squeeze=False, layout="constrained")
    try:
        for ax, name in zip(axes[0], names):
            methods = [m for m, values in panels[name].items() if len(values)]
            if not methods:
                ax.text(0.5, 0.5, "n/a: no run has a value", ha="center", va="center", transform=ax.transAxes)
                ax.set_axis_off()
                continue
            ax.boxplot([np.asarray(panels[name][m], dtype=float) for m in methods])
            ax.set_xticks(range(1, len(methods) + 1), methods, rotation=35, ha="right", fontsize=7)
            if name in zero_line:
                ax.axhline(0.0, color="0.4", lw=0.8)
            ax.set_ylabel(name, fontsize=8)
            ax.tick_params(axis="y", labelsize=7)
            ax.grid(alpha=0.3, axis="y")
        if title:
            fig.suptitle(title, fontsize=10)
        return save_figure(fig, path)
    finally:
        plt.close(fig)


def plot_memory_distance(
    path: str | Path,
    series: Mapping[str, tuple[np.ndarray, np.ndarray]],
    extrapolated: tuple[float, float] | None = None,
    limit_gib: float | None = None,
    title: str = "",
) -> Path:
    """Accounted memory [MiB] against distance [km] per method (left), and (right, when `extrapolated` gives
    (target km, all samples' GiB there)) the measured all-samples growth carried to the target beside the
    `limit_gib` line."""
    panels = 2 if extrapolated is not None else 1
    fig, axes = plt.subplots(1, panels, figsize=(5.2 * panels + 1.8, 4.0), squeeze=False, layout="constrained")
    try:
        ax = axes[0][0]
        for label, (distance, memory) in series.items():
            ax.plot(np.asarray(distance) / 1000.0, np.asarray(memory) / 2**20, label=label, lw=1.2)
        ax.set(xlabel="distance travelled [km]", ylabel="accounted memory [MiB]", title="measured")
        ax.grid(alpha=0.3)
        if extrapolated is not None:
            target_km, gib = extrapolated
            ax2 = axes[0][1]
            start = (0.0, 0.0)
            if "all" in series:
                distance, memory = (np.asarray(x, dtype=float) for x in series["all"])
                ax2.plot(distance / 1000.0, memory / 2**30, color="C0", label="all (measured)")
                start = (distance[-1] / 1000.0, memory[-1] / 2**30)
            ax2.plot(
                [start[0], target_km], [start[1], gib], "--", color="C0", label=f"all, extrapolated: {gib:.0f} GiB"
            )
            if limit_gib is not None:
                ax2.axhline(limit_gib, color="tab:red", lw=1.0, label=f"{limit_gib:.0f} GiB (the paper's machine)")
            ax2.set(
                xlabel="distance travelled [km]",
                ylabel="accounted memory [GiB]",
                title=f"all samples extrapolated to {target_km:.0f} km",
            )
            ax2.grid(alpha=0.3)
            top = max(gib, start[1], limit_gib or 0.0)
            ax2.set_ylim(0.0, 1.45 * top if top > 0 else 1.0)  # room above the data and the limit for the legend
            ax2.legend(fontsize=7, loc="upper left")
        fig.legend(*ax.get_legend_handles_labels(), loc="outside right center", fontsize=7)
        if title:
            fig.suptitle(title, fontsize=10)
        return save_figure(fig, path)
    finally:
        plt.close(fig)
