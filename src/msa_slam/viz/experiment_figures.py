"""Figures of online runs and experiment grids, as in the paper's Figs. 7-9: memory over time, per-step time
distributions, the box plot of ATE differences to all samples and parameter sweeps (matplotlib, Agg)."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from msa_slam.viz.labels import absent_note  # noqa: E402
from msa_slam.viz.save import save_figure  # noqa: E402


def _save(fig, path: str | Path) -> Path:
    try:
        return save_figure(fig, path)
    finally:
        plt.close(fig)


def plot_memory(
    path: str | Path, series: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]], title: str = "memory over time"
) -> Path:
    """series: label -> (frames, accounted bytes (keyframes + graph), RSS bytes); two panels in MiB."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), layout="constrained")
    for label, (frames, accounted, rss) in series.items():
        axes[0].plot(frames, np.asarray(accounted) / 2**20, label=label)
        axes[1].plot(frames, np.asarray(rss) / 2**20, label=label)
    axes[0].set(xlabel="frame", ylabel="accounted memory [MiB]", title="keyframes + graph (accounted)")
    axes[1].set(xlabel="frame", ylabel="resident set size [MiB]", title="process RSS")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    return _save(fig, path)


def idle_note(steps: Mapping[str, np.ndarray]) -> str:
    """What a step-time panel leaves out: per label, the steps that took 0 ms (idle: the step had nothing to
    do, or took less than the timer's resolution), which a log axis cannot place; "" when none."""
    counts = {label: (int((np.asarray(ms) <= 0).sum()), len(ms)) for label, ms in steps.items()}
    left_out = [
        f"{label} {idle} of {total}" if len(counts) > 1 else f"{idle} of {total} steps"
        for label, (idle, total) in counts.items()
        if idle
    ]
    if not left_out:
        return ""
    text = "left out, idle (0 ms, no place on a log axis): " + ", ".join(
        t.replace(" ", "\N{NO-BREAK SPACE}") for t in left_out
    )
    return textwrap.fill(text, 60, break_on_hyphens=False)


def plot_step_times(
    path: str | Path, steps: Mapping[str, Mapping[str, np.ndarray]], title: str = "per-step time"
) -> Path:
    """steps: step name -> (label -> per-step ms); one box-plot panel per step (log scale, as Fig. 8).
    Idle steps (0 ms) have no place on the log axis: each panel's x label counts those it leaves out, so a
    thin or empty box is not read as the whole story."""
    names = list(steps)
    fig, axes = plt.subplots(1, len(names), figsize=(4.5 * len(names), 4), squeeze=False)
    for ax, name in zip(axes[0], names):
        labels = list(steps[name])
        data = [np.asarray(steps[name][lab], dtype=float) for lab in labels]
        data = [d[d > 0] if (d > 0).any() else np.array([np.nan]) for d in data]
        ax.boxplot(data, showfliers=True, flierprops={"markersize": 2})
        ax.set_xticks(range(1, len(labels) + 1), labels, rotation=30, ha="right", fontsize=8)
        ax.set_yscale("log")
        ax.set(ylabel="time per step [ms]", title=name)
        ax.set_xlabel(idle_note(steps[name]), fontsize=8)
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


def plot_ate_difference(
    path: str | Path,
    differences: Mapping[str, Sequence[float]],
    title: str = "ATE difference to all samples",
    reference: str = "all",
    absent: Mapping[str, str] | None = None,
) -> Path:
    """Box plot per method of ATE(method) - ATE(`reference`) [m] over datasets/seeds (negative: better); the
    y label names the reference, as `report --reference` changes it; the x label names the `absent` methods
    (without a difference) and why."""
    labels = list(differences)
    fig, ax = plt.subplots(figsize=(max(5.0, 0.9 * len(labels) + 2), 4))
    ax.boxplot([np.asarray(differences[k], dtype=float) for k in labels])
    ax.set_xticks(range(1, len(labels) + 1), labels, rotation=30, ha="right", fontsize=8)
    ax.axhline(0.0, color="grey", lw=0.8)
    ax.set(ylabel=f"ATE - ATE({reference}) [m]", title=title)
    ax.set_xlabel(textwrap.fill(absent_note(absent or {}), 70), fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return _save(fig, path)


# MSA's distance bounds (eq. 7) are multiples of the stream's mean step, not metres: the axis says so
SWEPT_AXES = {"lambda_l": "lambda_l (x mean step)", "lambda_u": "lambda_u (x mean step)"}


def plot_sweeps(
    path: str | Path,
    sweeps: Mapping[str, Mapping[str, Mapping[str, tuple[Sequence[float], Sequence[float]]]]],
    title: str = "distance-bound ablation",
) -> Path:
    """sweeps: swept parameter -> metric -> line label (e.g. dataset) -> (values, metric means);
    one row per parameter, one column per metric (the paper's Fig. 9)."""
    params = list(sweeps)
    metrics = list(dict.fromkeys(m for p in params for m in sweeps[p]))
    fig, axes = plt.subplots(
        len(params),
        len(metrics),
        figsize=(3.6 * len(metrics), 3.0 * len(params) + 0.5),
        squeeze=False,
        layout="constrained",
    )
    for r, param in enumerate(params):
        for c, metric in enumerate(metrics):
            ax = axes[r][c]
            lines = {label: xy for label, xy in sweeps[param].get(metric, {}).items() if len(xy[0])}
            for label, (x, y) in lines.items():
                ax.plot(x, y, "o-", label=label)
            if not lines:  # every cell's value n/a (the cells' results.md say why): say so, not an empty frame
                ax.text(
                    0.5,
                    0.5,
                    "n/a in every cell\n(results.md gives the reason)",
                    ha="center",
                    va="center",
                    transform=ax.transAxes,
                    fontsize=9,
                    color="0.4",
                )
                ax.set(xticks=[], yticks=[])
            ax.set(xlabel=SWEPT_AXES.get(param, param), title=metric if r == 0 else "")
            ax.ticklabel_format(axis="y", useOffset=False)  # the metric's own values, not "+5.008e1" offsets
            ax.grid(alpha=0.3)
    handles, labels = next((h for h in (ax.get_legend_handles_labels() for ax in axes.flat) if h[0]), ([], []))
    if handles:  # below the panels, off the data
        fig.legend(handles, labels, loc="outside lower center", ncols=min(4, len(labels)), fontsize=8)
    fig.suptitle(title)
    return _save(fig, path)
