"""Figures a person can read: axis labels with units, equal aspect, legends off the data, loop
edges drawn, PR curves zoomed on their knee, sequence names without cache hashes."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.collections import PathCollection
from matplotlib.figure import Figure

from msa_slam.place_recognition.metrics import precision_recall
from msa_slam.viz.labels import display_name


@pytest.fixture
def figures(monkeypatch) -> list[Figure]:
    """The matplotlib figures the plot functions build, kept (and drawn) instead of only saved."""
    kept: list[Figure] = []

    def keep(fig, path, *args, **kwargs):
        fig.canvas.draw()
        kept.append(fig)

    monkeypatch.setattr(Figure, "savefig", keep)
    return kept


def _overlaps(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


@pytest.mark.parametrize(
    "name, shown",
    [
        ("figure-eight_hdl64_32fb48a0c1d2e3f4a5b6c7d8", "figure-eight (hdl64)"),
        ("loop_7b570b446c66ff1a9d7f1108", "loop"),
        ("kitti_06", "kitti_06"),
        ("00", "00"),
    ],
)
def test_display_name_drops_cache_hashes(name, shown):
    assert display_name(name) == shown


def _panel(n: int = 60, loops=((2, 50),), false_loops=((5, 30),)):
    from msa_slam.viz import TrajectoryPanel

    t = np.linspace(0, 2 * np.pi, n)
    xy = np.c_[40 * np.cos(t), 10 * np.sin(t)]
    return TrajectoryPanel("msa optimised", xy, np.linspace(0, 0.3, n), list(loops), list(false_loops))


def _route_axes(fig: Figure) -> list:
    """The trajectory panels of a figure: not the colour bar, not the zoom panel."""
    from msa_slam.viz.trajectories import ZOOM_LABEL

    return [ax for ax in fig.axes if ax.get_label() not in ("<colorbar>", ZOOM_LABEL) and ax.axison]


def test_trajectory_figure_has_units_equal_aspect_visible_loops_and_a_legend_off_the_axes(figures, tmp_path):
    from msa_slam.viz import plot_trajectories
    from msa_slam.viz.trajectories import FALSE_LOOP, TRUE_LOOP

    panel = _panel()
    plot_trajectories(tmp_path / "t.png", panel.xy, [panel, _panel(loops=((1, 40), (3, 45)))], title="x")
    fig = figures[-1]
    axes = _route_axes(fig)
    assert len(axes) == 2
    for ax in axes:
        assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "y [m]"
        assert ax.get_aspect() == 1.0
        assert ax.get_legend() is None
    rings = [
        [ln for ln in ax.get_lines() if ln.get_color() == colour and ln.get_marker() == marker]
        for ax in axes
        for colour, marker in ((TRUE_LOOP, "o"), (FALSE_LOOP, "s"))
    ]
    assert [len(ln.get_xdata()) for group in rings for ln in group] == [2, 2, 4, 2]  # both ends of every loop
    (legend,) = fig.legends
    box = legend.get_window_extent()
    assert not any(_overlaps(box, ax.get_window_extent()) for ax in axes)
    assert {t.get_text() for t in legend.get_texts()} >= {"ground truth", "loop (true)", "loop (false)"}


def test_loops_leave_the_keyframes_error_colours_visible(figures, tmp_path):
    """Loop edges run beneath the coloured keyframes and their end markers are hollow rings wider than a
    keyframe's dot, so the dot's colour shows inside: a loop must not hide the error it was meant to fix."""
    from msa_slam.viz import plot_trajectories
    from msa_slam.viz.trajectories import TRUE_LOOP

    panel = _panel(loops=[(k, k + 30) for k in range(0, 30, 2)], false_loops=())
    plot_trajectories(tmp_path / "t.png", panel.xy, [panel])
    (ax,) = _route_axes(figures[-1])
    (dots,) = [c for c in ax.collections if isinstance(c, PathCollection)]
    dot_diameter = float(np.sqrt(dots.get_sizes()[0]))
    loops = [ln for ln in ax.get_lines() if ln.get_color() == TRUE_LOOP]
    edges = [ln for ln in loops if ln.get_linestyle() != "None"]
    rings = [ln for ln in loops if ln.get_marker() == "o"]
    assert edges and rings
    assert all(ln.get_zorder() < dots.get_zorder() for ln in edges)
    for ring in rings:
        assert ring.get_markerfacecolor() == "none" and ring.get_zorder() > dots.get_zorder()
        assert ring.get_markersize() - ring.get_markeredgewidth() > dot_diameter


def _coverage(ax) -> float:
    """Share of the axes' area (in data units) that the bounding box of everything drawn on it covers."""
    points = [ln.get_xydata() for ln in ax.get_lines()] + [
        c.get_offsets() for c in ax.collections if len(c.get_offsets()) > 1
    ]
    xy = np.vstack([np.asarray(p, dtype=float) for p in points])
    xy = xy[np.isfinite(xy).all(axis=1)]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    return float(np.ptp(xy[:, 0]) * np.ptp(xy[:, 1]) / ((x1 - x0) * (y1 - y0)))


@pytest.mark.parametrize("width, height", [(450.0, 20.0), (20.0, 450.0), (80.0, 60.0)])
def test_trajectory_panels_are_fitted_to_the_route(figures, tmp_path, width, height):
    """A 450 x 20 m route on a square axis leaves ~95 % of each panel white: the panels take the route's extent
    and aspect (world axes kept), so the data covers at least half of every panel, however the route lies."""
    from msa_slam.viz import TrajectoryPanel, plot_trajectories

    t = np.linspace(0, 2 * np.pi, 200)
    gt = np.c_[width / 2 * np.cos(t), height / 2 * np.sin(t)]
    errors = np.abs(np.sin(3 * t))
    panels = [TrajectoryPanel(f"method {k}", gt + 0.3 * k, errors * (k + 1), [(0, 150)]) for k in range(8)]
    plot_trajectories(tmp_path / "t.png", gt, [TrajectoryPanel("odometry", gt + 2.0, 3 * errors), *panels])
    axes = _route_axes(figures[-1])
    assert len(axes) == 9
    for ax in axes:
        assert ax.get_aspect() == 1.0 and ax.get_adjustable() == "box"
        assert _coverage(ax) >= 0.5, ax.get_title()
        box = ax.get_window_extent()  # the drawn box keeps the route's shape: equal aspect, nothing stretched
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        assert box.width / box.height == pytest.approx((x1 - x0) / (y1 - y0), rel=0.02)


def test_a_zoom_panel_shows_where_the_methods_differ_most(figures, tmp_path):
    from msa_slam.viz import TrajectoryPanel, plot_trajectories
    from msa_slam.viz.trajectories import ZOOM_LABEL

    gt = np.c_[np.linspace(0, 400, 401), np.zeros(401)]
    same = np.full(401, 0.2)
    apart = same.copy()
    apart[300:320] = 1.0  # around x = 310 m one method is 0.8 m worse
    panels = [TrajectoryPanel("a", gt, same, []), TrajectoryPanel("b", gt, apart, [])]
    plot_trajectories(tmp_path / "t.png", gt, panels)
    (zoom,) = [ax for ax in figures[-1].axes if ax.get_label() == ZOOM_LABEL]
    x0, x1 = zoom.get_xlim()
    assert x0 < 310 < x1 and x1 - x0 < 150
    assert {ln.get_label() for ln in zoom.get_lines()} >= {"a", "b"}

    plot_trajectories(tmp_path / "t.png", gt, [TrajectoryPanel("a", gt, same, []), TrajectoryPanel("b", gt, same, [])])
    assert not [ax for ax in figures[-1].axes if ax.get_label() == ZOOM_LABEL]  # nothing differs: no zoom


def test_without_ground_truth_the_trajectory_figure_shows_no_ground_truth_artefacts(figures, tmp_path):
    """No error colour bar, no "ground truth" legend entry, no error colouring: there is no error to show."""
    from msa_slam.viz import TrajectoryPanel, plot_trajectories

    xy = _panel().xy
    panels = [
        TrajectoryPanel("odometry (no ground truth)", xy, None),
        TrajectoryPanel("msa optimised (no ground truth)", xy, None, [(2, 50)]),
    ]
    plot_trajectories(tmp_path / "t.png", np.empty((0, 2)), panels)
    fig = figures[-1]
    assert not [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    labels = {t.get_text() for legend in fig.legends for t in legend.get_texts()}
    assert not any("ground truth" in label and "no ground truth" not in label for label in labels)
    assert not any("ATE" in label for label in labels)
    assert all(c.get_array() is None for ax in _route_axes(fig) for c in ax.collections)


def test_metrics_figure_shows_differences_to_all_samples_keyframes_and_one_odometry_line(figures, tmp_path):
    """Like the paper's Fig. 5: each method's difference to all samples (a 0.707-0.730 m spread shows, not lost
    on a 0-1.3 m axis), keyframes and memory panels, the odometry's ATE one line rather than a bar per method."""
    from msa_slam.viz import MethodMetric, plot_method_metrics

    methods = ["all", "constant-1m", "msa"]
    ate = [0.707, 0.730, 0.715]
    plot_method_metrics(
        tmp_path / "m.png",
        methods,
        [
            MethodMetric("t. ATE", "m", ate, 3, difference=True),
            MethodMetric("R. ATE", "deg", [None, None, None], difference=True, why="no ground truth"),
            MethodMetric("t. ATE, every frame", "m", ate, 3, line=("odometry", 1.3)),
            MethodMetric("keyframes", "", [500, 120, 60], 0),
            MethodMetric("memory (keyframes + graph)", "MiB", [14.0, 6.0, 3.0]),
        ],
    )
    fig = figures[-1]
    titles = {ax.get_title(): ax for ax in fig.axes if ax.axison}
    assert {"t. ATE - all", "keyframes", "memory (keyframes + graph)"} <= set(titles)
    heights = [bar.get_height() for bar in titles["t. ATE - all"].patches]
    assert heights == pytest.approx([0.0, 0.023, 0.008])
    lo, hi = titles["t. ATE - all"].get_ylim()
    assert hi - lo < 0.1  # the axis spans the differences, not the ATE
    assert [bar.get_height() for bar in titles["keyframes"].patches] == [500, 120, 60]
    absolute = titles["t. ATE, every frame"]
    assert len(absolute.patches) == len(methods)  # no odometry bars
    assert [ln.get_ydata()[0] for ln in absolute.get_lines()] == [1.3]
    assert any("odometry" in t.get_text() for t in absolute.texts)
    assert "no ground truth" in titles["R. ATE"].texts[0].get_text()  # n/a says why, not an empty axis


def _curve(seed: int, good: float):
    rng = np.random.default_rng(seed)
    dist = rng.uniform(0, 20, 300)
    sims = np.clip(np.where(dist < 5, good, 0.5) + rng.normal(0, 0.08, 300), 0, 1)
    return precision_recall(sims, dist, 5.0)


def test_pr_figure_zooms_on_the_knee_when_curves_crowd_a_corner(figures, tmp_path):
    from msa_slam.place_recognition.figures import plot_pr_curves, zoom_limits

    crowded = {f"m{k}": _curve(k, 0.95) for k in range(7)}
    (r0, r1), (p0, p1) = zoom_limits(crowded)
    assert r1 - r0 < 0.6 or p1 - p0 < 0.6
    plot_pr_curves(crowded, tmp_path / "pr.png", title="t")
    fig = figures[-1]
    assert len(fig.axes) == 2 and fig.axes[1].get_xlim() == pytest.approx((r0, r1))
    for ax in fig.axes:
        assert ax.get_xlabel() == "recall" and ax.get_ylabel() == "precision" and ax.get_legend() is None
    styles = {(ln.get_linestyle(), ln.get_marker()) for ln in fig.axes[0].get_lines()}
    assert len(styles) == 7  # identical curves stay distinguishable
    (legend,) = fig.legends
    assert not any(_overlaps(legend.get_window_extent(), ax.get_window_extent()) for ax in fig.axes)


def test_pr_figure_explains_its_markers_and_names_every_method(figures, tmp_path):
    """Every method is in the legend or named as absent, with why; the legend says what the markers mark."""
    from msa_slam.place_recognition.figures import plot_pr_curves

    curves = {"msa": _curve(1, 0.9), "all": _curve(2, 0.8)}
    plot_pr_curves(curves, tmp_path / "pr.png", absent={"entropy": "no loop candidates"})
    (legend,) = figures[-1].legends
    text = " ".join([t.get_text() for t in legend.get_texts()] + [legend.get_title().get_text()]).replace("\n", " ")
    for method in ("msa", "all", "entropy (no loop candidates)"):
        assert method in text
    assert "markers: similarity thresholds 0.0, 0.1, ... 0.9" in text
    line = figures[-1].axes[0].get_lines()[0]
    marked = np.asarray(curves[line.get_label().split(" ")[0]].thresholds)[line.get_markevery()]
    assert marked == pytest.approx(np.arange(10) / 10)


def test_pr_figure_is_one_panel_when_curves_spread_over_the_square(figures, tmp_path):
    from msa_slam.place_recognition.figures import plot_pr_curves, zoom_limits

    spread = {"weak": _curve(1, 0.55), "fair": _curve(2, 0.7)}
    assert zoom_limits(spread) is None
    plot_pr_curves(spread, tmp_path / "pr.png")
    assert len(figures[-1].axes) == 1


def test_keyframe_figure_has_units_and_its_legend_off_the_path(figures, tmp_path):
    from msa_slam.sampling.figure import plot_keyframes

    poses = np.tile(np.eye(4), (50, 1, 1))
    poses[:, 0, 3] = np.linspace(0, 50, 50)
    poses[:, 1, 3] = np.sin(np.linspace(0, 6, 50)) * 10
    plot_keyframes(poses, [0, 10, 20, 30], tmp_path / "k.png", title="msa", flushed=[30])
    fig = figures[-1]
    (ax,) = fig.axes
    assert (ax.get_xlabel(), ax.get_ylabel(), ax.get_aspect()) == ("x [m]", "y [m]", 1.0)
    assert ax.get_legend() is None
    assert not _overlaps(fig.legends[0].get_window_extent(), ax.get_window_extent())


def test_step_time_panels_say_which_idle_steps_they_leave_out(figures, tmp_path):
    from msa_slam.viz import plot_step_times

    busy = np.linspace(0.1, 3.0, 40)
    loops = busy.copy()
    loops[:12] = 0.0  # idle keyframe steps: a log axis has no place for 0 ms
    plot_step_times(tmp_path / "s.png", {"graph update": {"msa": busy}, "loop detection": {"msa": loops}})
    plot_step_times(tmp_path / "m.png", {"loop detection": {"all": busy, "msa": loops, "never": np.zeros(5)}})
    single, multi = figures[-2], figures[-1]
    assert single.axes[0].get_xlabel() == ""  # nothing left out, nothing said
    note = single.axes[1].get_xlabel().replace("\N{NO-BREAK SPACE}", " ")
    assert "idle (0 ms" in note and "log axis" in note and "12 of 40 steps" in note
    note = " ".join(multi.axes[0].get_xlabel().replace("\N{NO-BREAK SPACE}", " ").split())
    assert "msa 12 of 40" in note and "never 5 of 5" in note and "all " not in note


def test_a_panel_without_loops_counts_none_in_its_title(figures, tmp_path):
    """The odometry panel: loops belong to the optimised estimates (compare draws one odometry panel beside all
    methods, so counting one method's loops there would mislead)."""
    from msa_slam.viz import TrajectoryPanel, plot_trajectories
    from msa_slam.viz.trajectories import TRUE_LOOP

    panel = _panel()
    odometry = TrajectoryPanel("odometry", panel.xy, panel.errors)
    plot_trajectories(tmp_path / "t.png", panel.xy, [odometry, panel])
    first, second = _route_axes(figures[-1])
    assert first.get_title() == "odometry\n60 keyframes" and not [
        ln for ln in first.get_lines() if ln.get_color() == TRUE_LOOP
    ]
    assert second.get_title() == "msa optimised\n60 keyframes, 1 loop, 1 false"  # not "1 loops"


def test_panel_titles_count_in_the_right_number(figures, tmp_path):
    from msa_slam.viz import plot_trajectories

    panels = [_panel(loops=(), false_loops=()), _panel(loops=((1, 40), (3, 45)), false_loops=())]
    plot_trajectories(tmp_path / "t.png", panels[0].xy, panels)
    titles = [ax.get_title() for ax in _route_axes(figures[-1])]
    assert titles == ["msa optimised\n60 keyframes, 0 loops", "msa optimised\n60 keyframes, 2 loops"]


def test_ate_difference_names_the_methods_it_leaves_out(figures, tmp_path):
    from msa_slam.viz import plot_ate_difference

    plot_ate_difference(tmp_path / "d.png", {"msa": [-0.1, 0.02]}, absent={"entropy": "ATE n/a on every cell"})
    assert "not shown: entropy (ATE n/a on every cell)" in figures[-1].axes[0].get_xlabel()


def test_figures_are_the_same_bytes_on_every_run(tmp_path):
    """Two runs write the same PNG bytes (no dates, no unordered iteration): result folders compare byte for
    byte and figures can be kept under version control."""
    from msa_slam.viz import MethodMetric, TrajectoryPanel, plot_method_metrics, plot_trajectories

    gt = np.c_[np.linspace(0, 400, 401), 5 * np.sin(np.linspace(0, 6, 401))]
    apart = np.full(401, 0.2)
    apart[300:320] = 1.0
    for name in ("a", "b"):
        plot_trajectories(
            tmp_path / f"t-{name}.png",
            gt,
            [TrajectoryPanel("x", gt, np.full(401, 0.2), [(0, 300)]), TrajectoryPanel("y", gt, apart, [])],
        )
        plot_method_metrics(
            tmp_path / f"m-{name}.png", ["all", "msa"], [MethodMetric("t. ATE", "m", [0.7, 0.72], difference=True)]
        )
    assert (tmp_path / "t-a.png").read_bytes() == (tmp_path / "t-b.png").read_bytes()
    assert (tmp_path / "m-a.png").read_bytes() == (tmp_path / "m-b.png").read_bytes()
