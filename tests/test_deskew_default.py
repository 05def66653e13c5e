"""KISS-ICP deskews by default when the scans carry per-point times (as kiss-icp does), not when they have none,
and `-p odometry.deskew=false` turns it off; metrics.json and report.md say which deskew was done and why."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from helpers.scans import write_bin
from test_inputs import _pcd, _write_bag
from test_real_inputs_times import N, _points
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.odometry.choice import make_odometry
from msa_slam.odometry.kiss import NO_POINT_TIMES
from msa_slam.pipeline.config import make_config
from msa_slam.sources import open_sequence


def _pcd_folder(root: Path) -> Path:
    """PCD scans with a per-point `t` field (ns over a 0.1 s sweep), as drivers write them."""
    for k in range(N):
        _pcd(root / f"{k:06d}.pcd", _points(k), np.linspace(0, 1e8, 400), "binary")
    return root


def _bin_folder(root: Path) -> Path:
    """Bare .bin scans: no per-point times."""
    for k in range(N):
        write_bin(root / f"{k:06d}.bin", _points(k))
    return root


def _metrics(command: str, dataset: Path, out: Path, *params: str, options: tuple[str, ...] = ()) -> tuple[dict, str]:
    result = CliRunner().invoke(
        app,
        [
            command,
            "-d",
            str(dataset),
            "--sampler",
            "all",
            "--mode",
            "realistic",
            "-q",
            "--cache-dir",
            str(out.parent / "cache"),
            "--out",
            str(out),
            *options,
            *[arg for p in params for arg in ("-p", p)],
        ],
    )
    assert result.exit_code == 0, result.output
    return json.loads((out / "metrics.json").read_text()), (out / "report.md").read_text()


def test_scans_with_a_time_field_are_deskewed_by_default(tmp_path):
    scans = _pcd_folder(tmp_path / "pcd")
    for command in ("run", "online"):
        m, report = _metrics(command, scans, tmp_path / command)
        assert (m["deskew"], m["deskew_from"]) == (True, "per-point times"), command
        assert "Odometry: deskew on (per-point times)." in report
    assert m["warnings"] == [w for w in m["warnings"] if NO_POINT_TIMES not in w]
    batch = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert batch["odometry_config"]["data"]["deskew"] is True


def test_a_bag_with_a_per_point_time_field_is_deskewed_by_default(tmp_path):
    bag = tmp_path / "run.bag"
    _write_bag(bag, "ros1")  # PointCloud2 with x, y, z and a per-point `t` (ns)
    m, report = _metrics("run", bag, tmp_path / "bag", options=("--topic", "/points"))
    assert (m["deskew"], m["deskew_from"], m["odometry_config"]["data"]["deskew"]) == (True, "per-point times", True)
    assert "Odometry: deskew on (per-point times)." in report


def test_deskew_false_turns_it_off(tmp_path):
    m, report = _metrics("run", _pcd_folder(tmp_path / "pcd"), tmp_path / "off", "odometry.deskew=false")
    assert (m["deskew"], m["deskew_from"], m["odometry_config"]["data"]["deskew"]) == (
        False,
        "odometry.deskew=false",
        False,
    )
    assert "Odometry: deskew off (odometry.deskew=false)." in report


def test_scans_without_point_times_are_not_deskewed_and_not_warned_about(tmp_path):
    """Off by default without per-point times; the note that deskew had no effect is only for a deskew asked."""
    m, report = _metrics("run", _bin_folder(tmp_path / "bin"), tmp_path / "default")
    assert (m["deskew"], m["deskew_from"]) == (False, "no per-point times")
    assert not any(NO_POINT_TIMES in w for w in m["warnings"])
    asked, _ = _metrics("run", tmp_path / "bin", tmp_path / "asked", "odometry.deskew=true")
    assert (asked["deskew"], asked["deskew_from"]) == (False, "no per-point times (odometry.deskew=true dropped)")
    assert any(NO_POINT_TIMES in w for w in asked["warnings"])


def test_simulated_sequences_are_deskewed_by_default(cache_dir):
    """The simulator writes per-point times (velodyne_times/), so its sequences are deskewed by default."""
    config = make_config(dataset="sim:test", cache_dir=str(cache_dir), source={"frames": 5})
    sequence = open_sequence(config.dataset, cache_dir=config.cache_dir, source=config.source)
    assert sequence.point_times
    assert make_odometry(config, len(sequence), sequence.point_times).config["data"]["deskew"] is True
