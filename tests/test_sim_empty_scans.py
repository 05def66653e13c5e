"""Simulated scans that see (almost) nothing: a max_range that cannot reach the ground is refused before the
world is built, an empty scan stops the simulation with nothing written (msa-slam cannot read such a
sequence back), and sparse scans give one warning naming how many and the settings to check."""

from __future__ import annotations

import sys
import warnings

import pytest

import msa_slam.sim.simulation
from msa_slam.datasets.sequences import kitti_sequence
from msa_slam.errors import InputError
from msa_slam.sim import get_sensor, make_config, simulate_sequence
from msa_slam.sim.coverage import (
    POINT_BYTES,
    SHORT_RANGE_M,
    check_reaches_ground,
    likely_settings,
    warn_short_range,
    warn_sparse_scans,
)


def _no_world(*args, **kwargs):
    raise AssertionError("the world was built before the settings were checked")


def test_a_max_range_short_of_the_ground_is_refused_before_the_world_is_built(tmp_path, monkeypatch):
    monkeypatch.setattr(msa_slam.sim.simulation, "build_world", _no_world)
    with pytest.raises(
        InputError,
        match=r"^simulation config: max_range=1\.5 m is shorter than the 4\.1 m at which "
        r"the lowest beam of hdl64 \(-24\.8 deg\) meets the ground from 1\.73 m up, "
        r"so the scans would be empty; give max_range >= 5 m or leave it unset",
    ):
        simulate_sequence(make_config(trajectory="kitti-07", end=3, max_range=1.5), out=tmp_path / "seq")
    assert list(tmp_path.iterdir()) == []


def test_the_ground_range_follows_the_sensor_height_and_lowest_beam():
    hdl64, os1 = get_sensor("hdl64", max_range=4.2), get_sensor("os1-64", max_range=4.2)
    check_reaches_ground(hdl64, 1.73)  # 1.73 / sin(24.8 deg) = 4.12 m
    with pytest.raises(InputError, match=r"4\.5 m at which the lowest beam of os1-64 \(-22\.5 deg\)"):
        check_reaches_ground(os1, 1.73)
    check_reaches_ground(get_sensor("os1-64", max_range=3.2), 1.2)  # a walking platform's sensor: 3.14 m
    with pytest.raises(InputError, match="max_range=2.8 m is shorter than the 2.9 m"):
        check_reaches_ground(get_sensor("hdl64", max_range=2.8), 1.2)


def test_cli_refuses_a_tiny_max_range_in_one_line(tmp_path, monkeypatch, capsys):
    from msa_slam.cli import main

    out = tmp_path / "cli"
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "msa-slam",
            "simulate",
            "--trajectory",
            "kitti-07",
            "--end",
            "3",
            "--max-range",
            "1.5",
            "--out",
            str(out),
            "-q",
        ],
    )
    with pytest.raises(SystemExit) as done:
        main()
    err = capsys.readouterr().err
    assert done.value.code == 2 and not out.exists()
    assert err.count("\n") == 1 and err.startswith("error: simulation config: max_range=1.5 m is shorter than")


@pytest.mark.parametrize("workers", [0, 1])
def test_an_empty_scan_stops_the_simulation_with_nothing_written(tmp_path, workers):
    config = make_config(trajectory="kitti-07", end=3, azimuth_steps=8, dropout=0.999, realism="clean")
    with pytest.raises(
        InputError,
        match=r"^simulate: scan 0 of 3 has no points, and msa-slam cannot read a "
        r"sequence with an empty scan; check dropout=0\.999, azimuth_steps=8 "
        r"\(nothing was written\)$",
    ):
        simulate_sequence(config, out=tmp_path / "seq", workers=workers)
    assert list(tmp_path.iterdir()) == []


def test_sparse_scans_warn_when_written_and_when_reused(tmp_path):
    config = make_config(trajectory="kitti-07", end=4, azimuth_steps=64, dropout=0.95, max_range=4.5, realism="clean")
    message = (
        r"^simulate: 4 of 4 scans have fewer than 200 points \(fewest \d+\), too few for odometry and "
        r"descriptors; check max_range=4\.5 m, dropout=0\.95, azimuth_steps=64$"
    )
    with pytest.warns(UserWarning, match=message) as written:
        path = simulate_sequence(config, out=tmp_path / "seq")
    with pytest.warns(UserWarning, match=message):
        assert simulate_sequence(config, out=tmp_path / "seq") == path  # the cached sequence
    assert sum("fewer than" in str(w.message) for w in written) == 1
    assert len(kitti_sequence(path).select()) == 4  # sparse, but readable


def test_scans_under_200_points_warn_as_odometry_degrades_there():
    """Scans of 100-200 points passed unwarned, though KISS-ICP's ATE on them is up to ten times that on dense
    scans (warn_sparse_scans' measurements)."""
    config = make_config(trajectory="kitti-05", dropout=0.998)
    with pytest.warns(
        UserWarning,
        match=r"^simulate: 1 of 3 scans have fewer than 200 points \(fewest 150\), too "
        r"few for odometry and descriptors; check dropout=0\.998$",
    ):
        warn_sparse_scans(config, [POINT_BYTES * n for n in (150, 200, 5000)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_sparse_scans(config, [POINT_BYTES * n for n in (200, 5000)])


def test_usual_scans_give_no_warning(tmp_path):
    config = make_config(trajectory="kitti-07", end=3, azimuth_steps=128, realism="clean")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        simulate_sequence(config, out=tmp_path / "seq")


def test_likely_settings_name_only_what_thins_the_scans():
    assert likely_settings(make_config(max_range=200.0, azimuth_steps=4000)) == (
        "no setting thins them: the sensor sees little around this trajectory"
    )
    assert likely_settings(make_config(max_range=30.0, sensor="os1-64", azimuth_steps=512)) == (
        "check max_range=30 m, azimuth_steps=512"
    )


def test_a_max_range_too_short_for_odometry_warns_when_written_and_reused(tmp_path):
    """Under SHORT_RANGE_M the scans hold only the ground and the nearest objects (warn_short_range's measurements):
    one warning when the sequence is written and again when it is reused; none at the limit or unset."""
    config = make_config(trajectory="kitti-07", end=2, azimuth_steps=64, max_range=12.0, realism="clean")
    message = r"^simulate: max_range=12 m leaves the scans only the ground and the nearest objects; odometry fails"
    for _ in range(2):
        with pytest.warns(UserWarning, match=message) as caught:
            simulate_sequence(config, out=tmp_path / "seq", workers=0)
        assert sum("max_range" in str(w.message) for w in caught) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_short_range(make_config(trajectory="kitti-07", max_range=SHORT_RANGE_M))
        warn_short_range(make_config(trajectory="kitti-07"))
