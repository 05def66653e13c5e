"""Live view: `msa-slam online --viewer-save run.rrd` records the scan, both trajectories,
keyframes and loops per frame; read back headless. Without rerun-sdk the option fails in one clear line."""

from __future__ import annotations

import json
import sys

import pytest
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.errors import InputError

runner = CliRunner()


def _online(sequence, odometry_file, cache_dir, out, *extra):
    return runner.invoke(
        app,
        [
            "online",
            "--dataset",
            str(sequence),
            "--odometry",
            str(odometry_file),
            "--cache-dir",
            str(cache_dir),
            "--out",
            str(out),
            "--quiet",
            *extra,
        ],
    )


def test_a_saved_recording_holds_every_logged_entity_per_frame(sequence, odometry_file, cache_dir, tmp_path):
    pytest.importorskip("rerun", reason="rerun-sdk (the optional viewer extra) is not installed")
    from rerun.chunk import RrdReader

    from msa_slam.viz.live import ENTITIES

    recording = tmp_path / "run.rrd"
    result = _online(sequence, odometry_file, cache_dir, tmp_path / "out", "--viewer-save", str(recording))
    assert result.exit_code == 0, result.output
    frames = json.loads((tmp_path / "out" / "metrics.json").read_text())["frames"]
    rows: dict[str, int] = {}
    for chunk in RrdReader(recording).stream():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    assert {f"/{e}" for e in ENTITIES} <= set(rows), sorted(rows)
    assert rows["/world/scan"] == rows["/world/odometry"] == frames
    assert 0 < rows["/world/optimised"] <= frames + 1


def test_viewer_save_never_replaces_a_users_file(sequence, odometry_file, cache_dir, tmp_path):
    pytest.importorskip("rerun", reason="rerun-sdk (the optional viewer extra) is not installed")
    mine = tmp_path / "notes.rrd"
    mine.write_text("mine")
    result = _online(sequence, odometry_file, cache_dir, tmp_path / "out", "--viewer-save", str(mine))
    assert isinstance(result.exception, InputError) and "the file exists" in str(result.exception)
    assert mine.read_text() == "mine" and not (tmp_path / "out").exists()


def test_viewer_without_rerun_is_one_clear_error_before_any_work(
    sequence, odometry_file, cache_dir, tmp_path, monkeypatch
):
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun raises ImportError
    result = _online(sequence, odometry_file, cache_dir, tmp_path / "out", "--viewer")
    assert isinstance(result.exception, InputError) and "pip install 'msa-slam[viewer]'" in str(result.exception)
    assert not (tmp_path / "out").exists()
