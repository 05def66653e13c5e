"""The sweep figure (the paper's Fig. 9) labels MSA's distance bounds as multiples of the mean step, the unit
eq. 7 gives them, and any other swept parameter by its name."""

from __future__ import annotations

import matplotlib.pyplot as plt
import pytest

from msa_slam.viz import experiment_figures


@pytest.fixture
def drawn(monkeypatch):
    """The figure plot_sweeps builds, kept open instead of written."""
    figures = []
    monkeypatch.setattr(experiment_figures, "_save", lambda fig, path: figures.append(fig) or path)
    yield figures
    for fig in figures:
        plt.close(fig)


def test_bounds_are_labelled_in_mean_steps_and_other_parameters_by_name(drawn, tmp_path):
    line = {"city": ([0.0, 0.5, 1.0], [10.0, 12.0, 11.0])}
    sweeps = {"lambda_l": {"F1": line}, "lambda_u": {"F1": line}, "window": {"F1": line}}
    experiment_figures.plot_sweeps(tmp_path / "s.png", sweeps)
    (fig,) = drawn
    assert [ax.get_xlabel() for ax in fig.axes] == [
        "lambda_l (x mean step)",
        "lambda_u (x mean step)",
        "window",
    ]


def test_the_reproduction_passes_the_bounds_by_name_so_the_axis_gives_their_unit():
    from msa_slam.experiments.reproduce import sweep_lines
    from msa_slam.experiments.rows import CellRow

    values = {"improvement_t_pct": None, "memory_vs_reference_pct": 50.0}
    rows = [
        CellRow("c", "online", "d", "sc", "msa", "msa", 0, "", {**values, "f1_max": f}, swept={"lambda_u": u})
        for u, f in ((1.0, 0.9), (10.0, 0.8), (10.0, 0.6))
    ]
    (bound,) = sweep_lines(rows)
    assert bound == "lambda_u" and experiment_figures.SWEPT_AXES[bound] == "lambda_u (x mean step)"
    (line,) = sweep_lines(rows)[bound]["F1-max"].values()
    assert line == ([1.0, 10.0], [0.9, 0.7])  # the mean of the two seeds at 10
