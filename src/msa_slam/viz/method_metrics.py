"""The methods' metrics figure, laid out like the paper's Fig. 5: a top row of each method's difference to the
reference method (all samples) in t. ATE, R. ATE, memory and time, so a 0.02 m spread between methods is not
lost on a 0-1.3 m axis, and a bottom row of absolute values (ATE with the odometry as one reference line,
keyframes, memory). A metric no method has is a panel saying why, not an empty axis."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from msa_slam.evaluation.display import fmt  # noqa: E402
from msa_slam.viz.save import save_figure  # noqa: E402

REFERENCE_LINE = "0.35"  # the odometry line and the zero of the difference panels


@dataclass(frozen=True)
class MethodMetric:
    """One panel: `values` per method (None: n/a), `why` says why a value is missing; `difference`: plotted as
    value - value(reference); `line`: (label, value) drawn once across the panel (the odometry's ATE)."""

    name: str
    unit: str
    values: Sequence[float | None]
    decimals: int = 2
    difference: bool = False
    why: str = ""
    line: tuple[str, float | None] | None = None


def _na_panel(ax, metric: MethodMetric, text: str) -> None:
    ax.text(0.5, 0.5, textwrap.fill(text, 34), ha="center", va="center", fontsize=8, transform=ax.transAxes)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(metric.name, fontsize=9)


def _draw(ax, methods: Sequence[str], metric: MethodMetric, reference: str) -> None:
    values = np.array([np.nan if v is None else v for v in metric.values], dtype=float)
    title = f"{metric.name} - {reference}" if metric.difference else metric.name
    if not np.isfinite(values).any():
        return _na_panel(ax, metric, f"n/a: {metric.why or 'no method has a value'}")
    if metric.difference:
        if reference not in methods or not np.isfinite(values[list(methods).index(reference)]):
            return _na_panel(
                ax, metric, f"n/a: no `{reference}` value to compare with" + (f" ({metric.why})" if metric.why else "")
            )
        values = values - values[list(methods).index(reference)]
    x = np.arange(len(methods))
    bars = ax.bar(
        x,
        np.nan_to_num(values),
        color=np.where(values < 0, "tab:green", "tab:blue") if metric.difference else "tab:blue",
        width=0.7,
    )
    signed = metric.difference  # a difference is signed, unless it rounds to zero (never "-0.000")
    labels = [
        fmt(v, f"+.{metric.decimals}f" if signed and round(v, metric.decimals) else f".{metric.decimals}f")
        for v in values
    ]
    ax.bar_label(bars, labels, fontsize=6, padding=1)
    if metric.difference:
        ax.axhline(0.0, color=REFERENCE_LINE, lw=0.8)
        ax.use_sticky_edges = False  # room for the value labels on both sides of 0
    if metric.line is not None and metric.line[1] is not None:
        ax.axhline(metric.line[1], color=REFERENCE_LINE, ls="--", lw=1.0)
        ax.text(
            1.0,
            metric.line[1],
            f" {metric.line[0]} {metric.line[1]:.{metric.decimals}f}",
            fontsize=7,
            va="bottom",
            ha="right",
            color=REFERENCE_LINE,
            transform=ax.get_yaxis_transform(),
        )
    ax.margins(y=0.15)
    ax.set_xticks(x, methods, rotation=35, ha="right", fontsize=7)
    ax.set_ylabel(f"{title} [{metric.unit}]" if metric.unit else title, fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.tick_params(axis="y", labelsize=7)
    ax.grid(axis="y", alpha=0.3)
    missing = [m for m, v in zip(methods, values) if not np.isfinite(v)]
    if missing:
        ax.set_xlabel(f"n/a: {', '.join(missing)}" + (f" ({metric.why})" if metric.why else ""), fontsize=7)


def plot_method_metrics(
    path: str | Path, methods: Sequence[str], metrics: Sequence[MethodMetric], reference: str = "all", title: str = ""
) -> Path:
    """Write the difference panels (top row) and the absolute ones (bottom row) of every method in `methods`
    order."""
    rows = [[m for m in metrics if m.difference], [m for m in metrics if not m.difference]]
    rows = [row for row in rows if row]
    columns = max(len(row) for row in rows)
    fig, axes = plt.subplots(
        len(rows),
        columns,
        figsize=(3.4 * columns + 0.4, 3.3 * len(rows) + 0.6),
        dpi=130,
        squeeze=False,
        layout="constrained",
    )
    try:
        for ax_row, row in zip(axes, rows):
            for ax, metric in zip(ax_row, row):
                _draw(ax, methods, metric, reference)
            for ax in ax_row[len(row) :]:
                ax.axis("off")
        if title:
            fig.suptitle(title, fontsize=10)
        return save_figure(fig, path)
    finally:
        plt.close(fig)
