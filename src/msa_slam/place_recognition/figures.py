"""PR-curve figure (PNG) comparing samplers or descriptors: the full unit square and, when the curves sit in
a corner of it, a zoom on that corner; overlapping curves stay apart by line style, the legend sits outside and
says what the markers mark and which methods have no curve."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping
from itertools import cycle
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from msa_slam.io.atomic import atomic_path  # noqa: E402
from msa_slam.place_recognition.metrics import PRCurve  # noqa: E402
from msa_slam.viz.labels import absent_note  # noqa: E402

STYLES = ("-", "--", "-.", ":")
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*")
KNEE = 0.8  # the zoom keeps the points whose F1 reaches this fraction of the weakest curve's F1-max
ZOOM_BELOW = 0.6  # zoom only when those points span less than this fraction of recall or precision
MARK_EVERY = 0.1  # markers sit on the similarity thresholds that are multiples of this


def marked(thresholds: np.ndarray) -> np.ndarray:
    """Indices of the thresholds a curve's markers sit on (multiples of MARK_EVERY), as the legend says."""
    steps = np.asarray(thresholds, dtype=float) / MARK_EVERY
    return np.flatnonzero(np.isclose(steps, np.round(steps), atol=1e-6))


def markers_note(curves: Mapping[str, PRCurve]) -> str:
    """What the markers mark: the similarity thresholds they sit on, one list for all curves."""
    shown = sorted(
        {round(float(t), 2) for c in curves.values() for t in np.asarray(c.thresholds)[marked(c.thresholds)]}
    )
    if not shown:
        return f"no markers (no threshold is a multiple of {MARK_EVERY:g})"
    listed = (
        ", ".join(f"{t:.1f}" for t in shown)
        if len(shown) <= 4
        else f"{shown[0]:.1f}, {shown[1]:.1f}, ... {shown[-1]:.1f}"
    )
    return f"markers: similarity thresholds {listed} (precision and recall of the candidates at least that similar)"


def zoom_limits(curves: Mapping[str, PRCurve]) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """(recall range, precision range) around every curve's knee (thresholds whose F1 is at least KNEE times
    the lowest F1-max), padded; None when that region already fills most of the unit square."""
    scored = [(c, c.f1_max) for c in curves.values() if c.f1_max]
    if not scored:
        return None
    floor = KNEE * min(f1_max for _, f1_max in scored)
    keep = [np.asarray(c.f1, dtype=float) >= floor for c, _ in scored]
    recall = np.concatenate([np.asarray(c.recall, dtype=float)[k] for (c, _), k in zip(scored, keep)])
    precision = np.concatenate([np.asarray(c.precision, dtype=float)[k] for (c, _), k in zip(scored, keep)])
    (r0, r1), (p0, p1) = (recall.min(), recall.max()), (precision.min(), precision.max())
    if r1 - r0 >= ZOOM_BELOW and p1 - p0 >= ZOOM_BELOW:
        return None
    pad_r, pad_p = max(0.05 * (r1 - r0), 0.02), max(0.05 * (p1 - p0), 0.02)
    return (max(0.0, r0 - pad_r), min(1.02, r1 + pad_r)), (max(0.0, p0 - pad_p), min(1.02, p1 + pad_p))


def plot_pr_curves(
    curves: Mapping[str, PRCurve],
    path: str | Path,
    title: str = "Precision-recall",
    absent: Mapping[str, str] | None = None,
) -> Path:
    """Write one PR curve per label to `path` as PNG (legend, sorted by PR-AUC, shows PR-AUC and F1-max; its
    title says what the markers mark and names the `absent` methods with why they have no curve)."""
    order = sorted(curves, key=lambda k: -(curves[k].auc or 0.0))
    zoom = zoom_limits(curves)
    fig, axes = plt.subplots(
        1, 2 if zoom else 1, figsize=(9 if zoom else 5.5, 4.8), dpi=150, squeeze=False, layout="constrained"
    )
    try:
        for ax, limits in zip(axes[0], [((0.0, 1.02), (0.0, 1.02)), *([] if zoom is None else [zoom])]):
            for label, style, marker in zip(order, cycle(STYLES), cycle(MARKERS)):
                curve = curves[label]
                auc = "n/a" if curve.auc is None else f"{curve.auc:.3f}"
                f1 = "n/a" if curve.f1_max is None else f"{curve.f1_max:.3f}"
                ax.plot(
                    curve.recall,
                    curve.precision,
                    ls=style,
                    marker=marker,
                    ms=3.5,
                    markevery=marked(curve.thresholds).tolist(),
                    lw=1.4,
                    alpha=0.85,
                    label=f"{label} (PR-AUC {auc}, F1-max {f1})",
                )
            ax.set(xlabel="recall", ylabel="precision", xlim=limits[0], ylim=limits[1])
            ax.set_title("all thresholds" if ax is axes[0][0] else "zoom on the knee", fontsize=9)
            ax.grid(alpha=0.3)
        caption = "\n".join(
            textwrap.fill(line, 120) for line in (markers_note(curves), absent_note(absent or {})) if line
        )
        fig.legend(
            *axes[0][0].get_legend_handles_labels(),
            loc="outside lower center",
            ncols=2,
            fontsize=7,
            frameon=False,
            title=caption,
            title_fontsize=7,
        )
        fig.suptitle(title, fontsize=10)
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    return Path(path)
