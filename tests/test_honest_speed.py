"""Speed figures are those of the whole pipeline as it ran: the online progress line, metrics.json and report.md
give the same frames per second and real-time factor, on a fresh cache and on one the batch pipeline filled,
where the odometry is replayed, counted with the time it took when computed and said to be replayed; the batch
pipeline's stage times count replayed stages the same way."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import pytest
from test_real_inputs_times import _kitti
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.evaluation.metrics import Timing
from msa_slam.evaluation.resources import throughput
from msa_slam.experiments.estimate import recorded_seconds

REPLAYED = "(odometry replayed from the cache, counted as computed)"
LINE = re.compile(r"^online (?P<label>.*): done \S+ in \S+ s, +(?P<fps>\S+) fps +RTF +(?P<rtf>\S+)x")


def _command(name: str, dataset: Path, root: Path, out: str) -> tuple[str, dict, str]:
    """`msa-slam NAME` (KISS-ICP, progress on) on `dataset` with the cache in `root`: (its output, metrics.json,
    report.md)."""
    result = CliRunner().invoke(
        app,
        [
            name,
            "-d",
            str(dataset),
            "--sampler",
            "all",
            "--mode",
            "realistic",
            "--cache-dir",
            str(root / "cache"),
            "--out",
            str(root / out),
        ],
    )
    assert result.exit_code == 0, result.output
    folder = root / out
    return result.output, json.loads((folder / "metrics.json").read_text()), (folder / "report.md").read_text()


def _progress_line(output: str) -> re.Match:
    lines = [m for m in map(LINE.match, output.splitlines()) if m]
    assert len(lines) == 1, output
    return lines[0]


def _same_speed(output: str, m: dict, report: str) -> re.Match:
    """The terminal's last progress line, metrics.json and report.md give one fps and real-time factor, that of
    the whole pipeline's seconds; the line is returned for its label."""
    line = _progress_line(output)
    fps, rtf = throughput(m["frames"], m["pipeline_time_s"], m["frame_rate_hz"])
    # metrics.json rounds pipeline_time_s to 0.1 ms: on a run of a few hundredths of a second that is more than 1e-3
    rel = max(1e-3, 0.5e-4 / m["pipeline_time_s"])
    assert m["fps"] == pytest.approx(fps, rel=rel) and m["realtime_factor"] == pytest.approx(rtf, rel=rel)
    assert (line["fps"], line["rtf"]) == (f"{m['fps']:.1f}", f"{m['realtime_factor']:.2f}")
    assert f"| {m['fps']:.1f} | {m['backend_fps']:.1f} | {m['realtime_factor']:.2f} |" in report
    # the whole pipeline holds every step (backend_total: all after the odometry, the descriptor included)
    assert m["pipeline_time_s"] >= m["time_s"]["odometry"] + m["time_s"]["backend_total"] - 1e-3
    return line


def test_online_speed_is_the_same_everywhere_fresh_and_replayed(tmp_path):
    data = _kitti(tmp_path / "seq")
    output, fresh, report = _command("online", data, tmp_path, "fresh")
    line = _same_speed(output, fresh, report)
    assert "replayed" not in line["label"] and "replayed" not in report
    assert not fresh["odometry_cached"] and fresh["replayed_time_s"] == {}

    _, batch, batch_report = _command("run", data, tmp_path, "batch")  # computes the odometry into the cache
    assert not batch["frontend_cached"]["odometry"] and "replayed" not in batch_report
    output, warm, report = _command("online", data, tmp_path, "warm")
    line = _same_speed(output, warm, report)
    assert line["label"].endswith(REPLAYED)
    assert warm["odometry_cached"] and warm["replayed_time_s"]["odometry"] > 0
    # the replayed odometry counts what computing it took (the batch run's registrations), frame by frame
    assert warm["time_s"]["odometry"] == pytest.approx(warm["replayed_time_s"]["odometry"], abs=1e-3)
    assert warm["replayed_time_s"]["odometry"] <= batch["frontend_time_s"]["odometry"]
    assert warm["pipeline_time_s"] >= warm["replayed_time_s"]["odometry"]
    assert "odometry replayed from the cache, counted with the time it took when computed" in report


def test_batch_stage_times_count_replayed_stages_as_computed(tmp_path):
    data = _kitti(tmp_path / "seq")
    _, fresh, _ = _command("run", data, tmp_path, "fresh")
    output, again, report = _command("run", data, tmp_path, "again")
    assert fresh["replayed_time_s"] == {} and again["frontend_cached"] == {
        "odometry": True,
        "descriptors": True,
        "clouds": True,
    }
    replayed = again["replayed_time_s"]
    assert set(replayed) == {"odometry", "descriptors", "clouds"} and replayed["odometry"] > 0
    for stage, seconds in replayed.items():  # read from the cache, plus the time it took when computed
        assert again["frontend_time_s"][stage] >= seconds
        assert seconds <= fresh["frontend_time_s"][stage]
    assert (
        "(odometry, descriptors, clouds replayed from the cache, counted with the time they took when computed)"
        in report
    )
    assert (
        f"front end replayed from the cache: odometry (computed in {replayed['odometry']:.1f} s), descriptors "
        f"(computed in {replayed['descriptors']:.1f} s), clouds (computed in {replayed['clouds']:.1f} s)"
    ) in output


def test_a_grid_estimate_counts_what_a_cell_spent_not_replayed_time():
    """A cell that replayed its front end spent its time reading it, not the time it counts as computed."""
    timing = Timing(
        stages={"odometry": 2.5, "sampling": 1.0, "backend_total": 1.0, "threshold_sweep": None},
        replayed_s={"odometry": 2.0, "descriptors": 2.75},
        frontend_s={"dataset": 0.5, "descriptors": 3.0},
    )
    assert recorded_seconds(timing) == pytest.approx(2.5 + 1.0 + 0.5 + 3.0 - 2.0 - 2.75)
    assert recorded_seconds(replace(timing, replayed_s={})) == pytest.approx(7.0)
