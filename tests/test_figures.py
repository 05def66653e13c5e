"""Figures a person can read: axis labels with units, equal aspect, legends off the data, loop
edges drawn, PR curves zoomed on their knee, sequence names without cache hashes."""

from __future__ import annotations

import numpy as np
import pytest
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


@pytest.mark.parametrize("name, shown", [
    ("figure-eight_hdl64_32fb48a0c1d2e3f4a5b6c7d8", "figure-eight (hdl64)"),
    ("loop_7b570b446c66ff1a9d7f1108", "loop"),
    ("kitti_06", "kitti_06"),
    ("00", "00"),
])
def test_display_name_drops_cache_hashes(name, shown):
    assert display_name(name) == shown


def _panel(n: int = 60, loops=((2, 50),), false_loops=((5, 30),)):
    from msa_slam.viz import TrajectoryPanel

    t = np.linspace(0, 2 * np.pi, n)
    xy = np.c_[40 * np.cos(t), 10 * np.sin(t)]
    return TrajectoryPanel("msa optimised", xy, np.linspace(0, 0.3, n), list(loops), list(false_loops))


def test_trajectory_figure_has_units_equal_aspect_visible_loops_and_a_legend_off_the_axes(figures, tmp_path):
    from msa_slam.viz import plot_trajectories
    from msa_slam.viz.trajectories import FALSE_LOOP, TRUE_LOOP

    panel = _panel()
    plot_trajectories(tmp_path / "t.png", panel.xy, [panel, _panel(loops=((1, 40), (3, 45)))], title="x")
    fig = figures[-1]
    axes = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert len(axes) == 2
    for ax in axes:
        assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "y [m]"
        assert ax.get_aspect() == 1.0
        assert ax.get_legend() is None
    loops = [[ln for ln in ax.get_lines() if ln.get_color() == colour] for ax in axes for colour in (TRUE_LOOP,
                                                                                                    FALSE_LOOP)]
    assert [len(x) for x in loops] == [1, 1, 2, 1]
    assert all(ln.get_zorder() > 3 for group in loops for ln in group)  # drawn over the keyframes
    (legend,) = fig.legends
    box = legend.get_window_extent()
    assert not any(_overlaps(box, ax.get_window_extent()) for ax in axes)
    assert {t.get_text() for t in legend.get_texts()} >= {"ground truth", "loop (true)", "loop (false)"}


def test_metric_bar_legends_cover_no_bar(figures, tmp_path):
    from msa_slam.viz import plot_metric_bars

    labels = ["all", "constant-1m", "msa"]
    plot_metric_bars(tmp_path / "m.png", labels, {
        "ATE translation [m]": {"odometry": [0.9, 0.9, 0.9], "optimised": [0.1, 0.85, 0.05]},
        "memory [MiB]": {"keyframes + graph": [14.0, 13.0, 6.0]},
    })
    fig = figures[-1]
    for ax in fig.axes:
        assert ax.get_ylabel().endswith("]")  # a unit
        legend = ax.get_legend()
        if legend is None:
            continue
        box = legend.get_window_extent()
        assert not any(_overlaps(box, bar.get_window_extent()) for bar in ax.patches)


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
    first, second = [ax for ax in figures[-1].axes if ax.get_label() != "<colorbar>"]
    assert first.get_title() == "odometry\n60 keyframes" and not [ln for ln in first.get_lines()
                                                                  if ln.get_color() == TRUE_LOOP]
    assert second.get_title() == "msa optimised\n60 keyframes, 1 loop, 1 false"  # not "1 loops"


def test_panel_titles_count_in_the_right_number(figures, tmp_path):
    from msa_slam.viz import plot_trajectories

    panels = [_panel(loops=(), false_loops=()), _panel(loops=((1, 40), (3, 45)), false_loops=())]
    plot_trajectories(tmp_path / "t.png", panels[0].xy, panels)
    titles = [ax.get_title() for ax in figures[-1].axes if ax.get_label() != "<colorbar>"]
    assert titles == ["msa optimised\n60 keyframes, 0 loops", "msa optimised\n60 keyframes, 2 loops"]
