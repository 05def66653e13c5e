"""A result folder records what ran: config.yaml with the deskew actually done (off for scans without per-point
times), report.md with the run's warnings and its counts in the right number, figure titles naming the part of
the sequence read; an online run on scans without timestamps says so in one line."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.metrics import edited, metrics_json
from matplotlib.figure import Figure
from test_single_open import _untimed_folder

from msa_slam.datasets.options import SourceOptions
from msa_slam.datasets.sequences import UNTIMED, _warn_untimed
from msa_slam.odometry.kiss import NO_POINT_TIMES
from msa_slam.pipeline import LiveFrontEnd, run
from msa_slam.pipeline.config import load_config, make_config, make_online_config
from msa_slam.reporting.report import report_markdown
from msa_slam.reporting.results import write_run_files
from msa_slam.reporting.sequence_text import sequence_title
from msa_slam.slam import RunResult
from msa_slam.sources import open_source

DESKEW = {"max_range": 30.0, "deskew": True}  # asked, but the .bin scans carry no per-point times


@pytest.fixture(scope="module")
def batch(tmp_path_factory) -> tuple[RunResult, Path]:
    """A KISS-ICP batch run from scan 1 of an untimed .bin folder, asked to deskew, and its result folder."""
    root = tmp_path_factory.mktemp("untimed")
    scans, _ = _untimed_folder(root)
    config = make_config(
        dataset=str(scans),
        mode="realistic",
        sampler="all",
        odometry_params=DESKEW,
        cache_dir=str(root / "cache"),
        source={"first": 1},
    )
    result = run(config)
    out = root / "out"
    out.mkdir()
    write_run_files(result, out)
    return result, out


def test_config_yaml_records_the_deskew_done_and_re_runs_it(batch, caplog):
    result, out = batch
    assert yaml.safe_load((out / "config.yaml").read_text())["odometry_params"] == {**DESKEW, "deskew": False}
    assert json.loads((out / "metrics.json").read_text())["odometry_config"]["data"]["deskew"] is False
    with caplog.at_level(logging.WARNING, logger="msa_slam.odometry"):
        again = run(load_config(out / "config.yaml"))
    assert [r.getMessage() for r in caplog.records] == []  # it asks for what ran: nothing to switch off
    assert metrics_json(again)["frontend_cached"]["odometry"]  # and finds the first run's odometry
    np.testing.assert_array_equal(again.odometry, result.odometry)


def test_report_lists_the_warnings_of_the_run(batch):
    report = (batch[1] / "report.md").read_text()
    assert f"- warning: scans: {UNTIMED}\n" in report
    assert f"- warning: {NO_POINT_TIMES}\n" in report


def test_report_counts_loop_candidates_in_the_right_number(batch):
    for candidates, text in ((1, "; 1 loop candidate (similarity"), (2, "; 2 loop candidates (similarity")):
        result = edited(batch[0], lambda m: m.update(candidates=candidates))
        assert text in report_markdown(result, [], set())


@pytest.mark.parametrize(
    "source, frames, title",
    [
        (SourceOptions(), 12, "figure-eight (hdl64)"),
        (SourceOptions(frames=200), 200, "figure-eight (hdl64), scans 0-199"),
        (SourceOptions(first=100, frames=50), 50, "figure-eight (hdl64), scans 100-149"),
        (SourceOptions(first=1, jump=2), 5, "figure-eight (hdl64), scans 1, 3, ... 9"),
    ],
)
def test_sequence_title_names_the_part_read(source, frames, title):
    assert sequence_title("figure-eight_hdl64_32fb48a0c1d2e3f4a5b6c7d8", source, frames) == title


def test_figure_titles_name_the_scans_read(batch, tmp_path, monkeypatch):
    titles: list[str] = []
    real = Figure.savefig

    def recording(fig, *args, **kwargs):
        titles.append(fig.get_suptitle())
        return real(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", recording)
    write_run_files(batch[0], tmp_path)
    assert titles == ["scans, scans 1-5: all (5 keyframes, 0 loops, realistic mode)"]


def test_online_on_untimed_scans_warns_once_and_records_what_ran(tmp_path, caplog):
    scans, _ = _untimed_folder(tmp_path)
    config = make_online_config(dataset=str(scans), mode="realistic", sampler="all", odometry_params=DESKEW)
    _warn_untimed.cache_clear()  # warned once a folder and process
    with caplog.at_level(logging.WARNING):
        result = run(config, LiveFrontEnd(open_source(config.dataset)))
    untimed = [r.getMessage() for r in caplog.records if "no timestamps" in r.getMessage()]
    assert untimed == [f"{scans}: {UNTIMED}"]
    assert result.config.odometry_params == {**DESKEW, "deskew": False}
    assert metrics_json(result)["warnings"][:2] == [f"scans: {UNTIMED}", NO_POINT_TIMES]
