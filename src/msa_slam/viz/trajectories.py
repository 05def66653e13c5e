"""Trajectory figures: ground truth, odometry and optimised keyframes coloured by their error, loops marked.

Estimates are drawn after the same SE(3) alignment the ATE uses, so colour and position tell one story
(like the paper's Fig. 6, which colours trajectories by error).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import (
    Normalize,  # noqa: E402
    to_rgb,  # noqa: E402
)
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from msa_slam.viz.labels import counted  # noqa: E402
from msa_slam.viz.layout import FRAME_H_IN, FRAME_W_IN, MAX_HEIGHT_IN, data_limits, fit_to_data, panel_grid  # noqa: E402
from msa_slam.viz.save import save_figure  # noqa: E402


@dataclass(frozen=True)
class TrajectoryPanel:
    """One panel: an estimate's xy (K, 2) with per-point error (m; None without ground truth: drawn in one
    colour), and loops as index pairs into it (None: an estimate loops play no part in, such as the odometry,
    whose title then counts none); `false_loops`: those whose measured pose is false (evaluation.loops).
    `keyframes` None: every point is a keyframe (a dot); else xy is every frame's path, drawn as a line, with the
    keyframes at these indices as rings."""

    title: str
    xy: np.ndarray
    errors: np.ndarray | None
    loops: Sequence[tuple[int, int]] | None = None
    false_loops: Sequence[tuple[int, int]] = ()
    keyframes: Sequence[int] | None = None

    def counts(self) -> str:
        """What the panel's points are: "120 keyframes", "40 keyframes of 300 frames" or "300 frames"."""
        if self.keyframes is None:
            return counted(len(self.xy), "keyframe")
        if len(self.keyframes):
            return f"{counted(len(self.keyframes), 'keyframe')} of {counted(len(self.xy), 'frame')}"
        return counted(len(self.xy), "frame")

    @property
    def name(self) -> str:
        """The title up to its first comma (the estimate, without its ATE), as the zoom panel's legend names it."""
        return self.title.split("\n")[0].split(",")[0]


TRUE_LOOP, FALSE_LOOP = "tab:orange", "tab:red"  # loop colours kept off the error colour map (viridis)
PLAIN = "tab:blue"  # an estimate without errors to colour it by
GROUND_TRUTH = "0.8"
DOT = 5.0  # keyframe dot area (points^2); a loop's ring is wider, so the dot's error colour shows inside it
KEYFRAME_RING, KEYFRAME_EDGE = "0.15", 0.5  # a keyframe on a path of every frame: a hollow dark ring over the line
RING, RING_EDGE = 4.5, 0.7  # loop end markers (true: circle, false: square): hollow, size and edge width in points
ZOOM_LABEL = "zoom"  # the zoom panel's axes label (the route panels have none)
ZOOM_ERRORS, ZOOM_MIN_M, ZOOM_MAX = 25.0, 10.0, 0.3  # zoom side: 25 x the mean error, >= 10 m, <= 30 % of route
ZOOM_CENTRES = 200  # ground-truth points tried as the zoom's centre
TOP_PERCENTILE = 95  # of the compared panels' errors: the colour scale's top
ZOOM_FRAME_IN = 1.6  # the zoom panel's title (3 lines), x ticks and label, and legend (4 lines), in inches


def _draw(ax, gt_xy: np.ndarray, panel: TrajectoryPanel, norm: Normalize, cmap: str):
    """The panel's estimate, coloured by error, over the ground truth; loop edges beneath the keyframes and
    their hollow rings above: the error colours stay visible where loops crowd."""
    if len(gt_xy):
        ax.plot(gt_xy[:, 0], gt_xy[:, 1], color=GROUND_TRUTH, lw=3.0, zorder=1)
    segments = np.stack([panel.xy[:-1], panel.xy[1:]], axis=1)
    dots = panel.keyframes is None  # else a path of every frame: a line, its keyframes ringed
    width = 1.2 if dots else 1.8
    if panel.errors is None:
        lines = LineCollection(segments, colors=PLAIN, lw=width, zorder=2)
        if dots:
            ax.scatter(panel.xy[:, 0], panel.xy[:, 1], color=PLAIN, s=DOT, zorder=3)
    else:
        lines = LineCollection(segments, cmap=cmap, norm=norm, lw=width, zorder=2)
        lines.set_array(0.5 * (panel.errors[:-1] + panel.errors[1:]))
        if dots:
            ax.scatter(panel.xy[:, 0], panel.xy[:, 1], c=panel.errors, cmap=cmap, norm=norm, s=DOT, zorder=3)
    ax.add_collection(lines)
    if not dots and len(panel.keyframes):
        ring = panel.xy[np.asarray(panel.keyframes, dtype=int)]
        ax.plot(
            ring[:, 0],
            ring[:, 1],
            ls="none",
            marker="o",
            ms=RING,
            mfc="none",
            mec=KEYFRAME_RING,
            mew=KEYFRAME_EDGE,
            zorder=3,
        )
    # A loop between nearby keyframes is a short edge that a line alone would hide: its ends get rings.
    for pairs, colour, marker in ((panel.loops or (), TRUE_LOOP, "o"), (panel.false_loops, FALSE_LOOP, "s")):
        if len(pairs):
            ends = panel.xy[np.asarray(pairs, dtype=int)]  # (loops, 2 ends, xy)
            edges = np.full((len(ends), 3, 2), np.nan)
            edges[:, :2] = ends
            ax.plot(*edges.reshape(-1, 2).T, color=colour, lw=0.8, alpha=0.7, zorder=2.5)
            ax.plot(
                *ends.reshape(-1, 2).T,
                ls="none",
                color=colour,
                marker=marker,
                ms=RING,
                mfc="none",
                mew=RING_EDGE,
                zorder=4,
            )
    counts = (
        ""
        if panel.loops is None
        else (
            f", {counted(len(panel.loops), 'loop')}"
            + (f", {len(panel.false_loops)} false" if len(panel.false_loops) else "")
        )
    )
    ax.set_title(f"{panel.title}\n{panel.counts()}{counts}", fontsize=8)
    ax.set_xlabel("x [m]", fontsize=8)
    ax.set_ylabel("y [m]", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    return lines if panel.errors is not None else None


def zoom_window(gt_xy: np.ndarray, panels: Sequence[TrajectoryPanel]) -> tuple[np.ndarray, float] | None:
    """(centre, side in metres) of the square along the ground truth where the estimates' mean errors differ
    most (the panels of `_compared`); None without ground truth or errors, or where nothing differs."""
    compared = _compared(panels)
    if len(compared) < 2 or not len(gt_xy):
        return None
    typical = float(np.mean([np.mean(p.errors) for p in compared]))
    extent = float(np.ptp(gt_xy, axis=0).max())
    side = min(max(ZOOM_ERRORS * typical, ZOOM_MIN_M), ZOOM_MAX * extent)  # typical errors show at this scale
    centres = gt_xy[:: max(1, len(gt_xy) // ZOOM_CENTRES)]
    spread = np.zeros(len(centres))
    for i, centre in enumerate(centres):
        means = [
            float(p.errors[inside].mean())
            for p in compared
            if (inside := (np.abs(p.xy - centre) <= side / 2).all(axis=1)).any()
        ]
        spread[i] = max(means) - min(means) if len(means) > 1 else 0.0
    best = int(np.argmax(spread))
    return (centres[best], side) if spread[best] > 0 else None


def _draw_zoom(ax, gt_xy: np.ndarray, panels: Sequence[TrajectoryPanel], centre: np.ndarray, side: float) -> None:
    """Every estimate in its own colour (the error colours of the other panels would blend here) inside the zoom
    square, titled with the mean errors found there."""
    ax.set_label(ZOOM_LABEL)
    ax.plot(gt_xy[:, 0], gt_xy[:, 1], color=GROUND_TRUTH, lw=3.0, zorder=1, label="ground truth")
    colours = [c for c in plt.get_cmap("tab10").colors if c not in (to_rgb(TRUE_LOOP), to_rgb(FALSE_LOOP))]
    means = []
    for k, panel in enumerate(panels):
        inside = (np.abs(panel.xy - centre) <= side / 2).all(axis=1)
        if panel.errors is not None and inside.any():
            means.append(float(panel.errors[inside].mean()))
        marks = None if panel.keyframes is None else [int(i) for i in panel.keyframes]  # a path: its keyframes
        ax.plot(
            panel.xy[:, 0],
            panel.xy[:, 1],
            "-o",
            color=colours[k % len(colours)],
            lw=1.0,
            ms=2.5,
            zorder=2,
            label=panel.name,
            markevery=marks,
        )
    half = side / 2
    ax.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half))
    ax.set_aspect("equal", adjustable="box")
    here = f"mean ATE here {min(means):.3f}-{max(means):.3f} m" if means else ""
    ax.set_title(f"zoom on the black square ({side:.0f} m):\nwhere the errors differ most\n{here}", fontsize=8)
    ax.set_xlabel("x [m]", fontsize=8)
    ax.set_ylabel("y [m]", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)


def _legend_handles(gt_xy: np.ndarray, panels: Sequence[TrajectoryPanel], cmap: str, zoom: bool) -> list[Line2D]:
    coloured = any(p.errors is not None for p in panels)
    handles = [Line2D([], [], color=GROUND_TRUTH, lw=3.0, label="ground truth")] if len(gt_xy) else []
    if any(p.keyframes is None for p in panels):
        handles.append(
            Line2D(
                [],
                [],
                color=plt.get_cmap(cmap)(0.5) if coloured else PLAIN,
                marker="o",
                ms=3,
                lw=1.2,
                label="keyframes, SE(3)-aligned to ground truth (colour: ATE)"
                if coloured
                else "keyframes (no ground truth: no error to colour them by)",
            )
        )
    if any(p.keyframes is not None for p in panels):
        handles.append(
            Line2D(
                [],
                [],
                color=plt.get_cmap(cmap)(0.5) if coloured else PLAIN,
                lw=1.8,
                label="every frame, SE(3)-aligned to ground truth (colour: ATE)"
                if coloured
                else "every frame (no ground truth: no error to colour it by)",
            )
        )
    if any(p.keyframes is not None and len(p.keyframes) for p in panels):
        handles.append(
            Line2D(
                [],
                [],
                ls="none",
                marker="o",
                ms=RING,
                mfc="none",
                mec=KEYFRAME_RING,
                mew=KEYFRAME_EDGE,
                label="keyframe",
            )
        )
    if any(p.loops for p in panels):
        handles.append(
            Line2D(
                [],
                [],
                color=TRUE_LOOP,
                marker="o",
                ms=RING,
                mfc="none",
                lw=0.8,
                label="loop (true)" if len(gt_xy) else "loop (not judged: no ground truth)",
            )
        )
    if any(len(p.false_loops) for p in panels):
        handles.append(Line2D([], [], color=FALSE_LOOP, marker="s", ms=RING, mfc="none", lw=0.8, label="loop (false)"))
    if zoom:
        handles.append(
            Line2D([], [], color="k", lw=0.8, marker="s", ms=6, mfc="none", ls="none", label="zoomed square")
        )
    return handles


def _compared(panels: Sequence[TrajectoryPanel]) -> list[TrajectoryPanel]:
    """The panels with errors (all finite) that the colour scale and the zoom are about: the methods' (those loops
    belong to), or every panel with errors when fewer than two are methods' (a run: odometry and optimised)."""
    scored = [p for p in panels if p.errors is not None and len(p.errors) and np.isfinite(p.errors).all()]
    methods = [p for p in scored if p.loops is not None]
    return methods if len(methods) >= 2 else scored


def _grid(panels: Sequence[TrajectoryPanel], extents: Sequence[np.ndarray]) -> tuple[int, float, list[float]]:
    """(columns, axes width, axes height per row) in inches: the grid chosen by the panels' median aspect, each row
    as tall as its tallest panel, shrunk as a whole when the rows would not fit MAX_HEIGHT_IN."""
    aspects = []
    for extent in extents:
        (x0, x1), (y0, y1) = data_limits(extent)
        aspects.append((x1 - x0) / (y1 - y0))
    columns, width = panel_grid(len(panels), float(np.median(aspects)))
    heights = [max(width / a for a in aspects[r : r + columns]) for r in range(0, len(panels), columns)]
    room = MAX_HEIGHT_IN - len(heights) * FRAME_H_IN
    scale = min(1.0, room / sum(heights)) if room > 0 else 1.0
    return columns, width * scale, [h * scale for h in heights]


def plot_trajectories(
    path: str | Path, gt_xy: np.ndarray, panels: Sequence[TrajectoryPanel], title: str = "", cmap: str = "viridis"
) -> Path:
    """Write the panels, each fitted to its data at equal aspect and laid out by the route's aspect (one column
    of strips for a long thin route), with one colour scale of the error in metres set by the methods' panels
    (an odometry beyond it saturates; no scale without errors), a zoom panel on the right where the estimates
    differ most, and one legend below."""
    gt_xy = np.asarray(gt_xy, dtype=float).reshape(-1, 2)
    extents = [np.vstack([gt_xy, p.xy]) for p in panels]
    columns, width, heights = _grid(panels, extents)
    zoom = zoom_window(gt_xy, panels)
    grid_w, grid_h = columns * (width + FRAME_W_IN) + 1.2, sum(heights) + len(heights) * FRAME_H_IN  # 1.2: colour bar
    # the zoom's axes: as tall as the panels leave room for beside its title and legend, within 2.5-4 inches
    zoom_side = float(np.clip(grid_h - ZOOM_FRAME_IN, 2.5, 4.0)) if zoom else 0.0
    zoom_w = zoom_side + FRAME_W_IN if zoom else 0.0
    fig = plt.figure(
        figsize=(grid_w + zoom_w, max(grid_h, zoom_side + ZOOM_FRAME_IN if zoom else 0.0) + 1.1),
        dpi=130,
        layout="constrained",
    )
    fig.get_layout_engine().set(w_pad=0.1)  # inches: the zoom's right edge off the figure's
    try:
        left, right = fig.subfigures(1, 2, width_ratios=[grid_w, zoom_w]) if zoom else (fig, None)
        axes = left.subplots(len(heights), columns, squeeze=False, gridspec_kw={"height_ratios": heights}).ravel()
        scaled = _compared(panels)
        # the colour scale's top: most of the methods' errors, so one method's outliers (or the odometry's drift)
        # do not leave every other keyframe the same dark colour; larger errors take the top colour
        top = float(np.percentile(np.concatenate([p.errors for p in scaled]), TOP_PERCENTILE)) if scaled else 1.0
        norm = Normalize(0.0, max(top, 1e-6))
        mappable = None
        for ax, panel, extent in zip(axes, panels, extents):
            mappable = _draw(ax, gt_xy, panel, norm, cmap) or mappable
            fit_to_data(ax, extent)
            if zoom:
                (cx, cy), side = zoom
                ax.add_patch(
                    Rectangle((cx - side / 2, cy - side / 2), side, side, fill=False, ec="k", lw=0.8, zorder=5)
                )
        for ax in axes[len(panels) :]:
            ax.axis("off")
        if mappable is not None:
            over = any(float(np.max(p.errors)) > top for p in panels if p.errors is not None)
            left.colorbar(
                mappable,
                ax=axes[: len(panels)].tolist(),
                shrink=0.6,
                extend="max" if over else "neither",
                label=f"ATE per {'keyframe' if all(p.keyframes is None for p in panels) else 'frame'} [m]"
                + (" (larger: top colour)" if over else ""),
            )
        if zoom:
            zoom_ax = right.subplots()
            _draw_zoom(zoom_ax, gt_xy, scaled, *zoom)
            zoom_ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), fontsize=7, frameon=False, ncols=1)
        fig.legend(
            handles=_legend_handles(gt_xy, panels, cmap, zoom is not None),
            loc="outside lower center",
            ncols=3,
            fontsize=8,
            frameon=False,
        )
        if title:
            fig.suptitle(title, fontsize=10)
        return save_figure(fig, path)
    finally:
        plt.close(fig)
