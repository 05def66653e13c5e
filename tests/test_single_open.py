"""A run opens its dataset once (the sampler-window check runs where the front end has the opened sequence),
deskew without per-point times is decided once where the odometry is made, a damaged scan 0 outside the
selection (--first) does not stop a run, and the online progress line counts the accepted loops."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from helpers.scans import write_bin
from test_real_inputs_times import COARSE, _coarse, _kitti, _points
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.datasets import open_dataset
from msa_slam.datasets.options import SourceOptions
from msa_slam.datasets.sequences import _warn_untimed
from msa_slam.errors import InputError
from msa_slam.experiments.compare import run_compare
from msa_slam.io.poses import write_poses
from msa_slam.odometry import KissOdometry
from msa_slam.pipeline import run
from msa_slam.pipeline.config import make_config, make_online_config
from msa_slam.pipeline.frontend import CONFIG_WINDOW_FIX, prepare_frontend
from msa_slam.pipeline.live import make_online_odometry
from msa_slam.sources import open_sequence
from msa_slam.sources import sequence as source_module
from msa_slam.types import FrameSource

FRAMES = 6
NO_POINT_TIMES = "odometry: no per-point times: deskewing has no effect (recorded as deskew false)"


def _untimed_folder(root: Path, frames: int = FRAMES) -> tuple[Path, Path]:
    """A folder of .bin scans without times, and a pose file moving 1.5 m a scan (its odometry)."""
    for k in range(frames):
        write_bin(root / "scans" / f"{k:06d}.bin", _points(k))
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, 0, 3] = 1.5 * np.arange(frames)
    write_poses(root / "odometry.txt", poses)
    return root / "scans", root / "odometry.txt"


def _counting_opens(monkeypatch) -> list[str]:
    """The paths msa_slam.sources opens (every run opens its dataset through open_sequence)."""
    opened: list[str] = []
    real = source_module.open_source_options

    def counting(path, kind, options, parsed=None):
        opened.append(str(path))
        return real(path, kind, options, parsed)

    monkeypatch.setattr(source_module, "open_source_options", counting)
    return opened


def _config(tmp_path: Path, **fields):
    scans, odometry = _untimed_folder(tmp_path)
    return make_config(
        **{
            "dataset": str(scans),
            "odometry": str(odometry),
            "mode": "realistic",
            "sampler": "all",
            "cache_dir": str(tmp_path / "cache"),
            **fields,
        }
    )


def _command(name: str, tmp_path: Path, *options: str, frames: int = FRAMES):
    """`msa-slam NAME` in this process on an untimed folder with its pose-file odometry."""
    scans, odometry = _untimed_folder(tmp_path, frames)
    return CliRunner().invoke(
        app,
        [
            name,
            "-d",
            str(scans),
            "--odometry",
            str(odometry),
            "--mode",
            "realistic",
            "--out",
            str(tmp_path / "out"),
            "--cache-dir",
            str(tmp_path / "cache"),
            "-q",
            *options,
        ],
    )


def test_run_opens_its_dataset_once_and_warns_once_that_it_has_no_timestamps(tmp_path, monkeypatch, caplog):
    opened = _counting_opens(monkeypatch)
    _warn_untimed.cache_clear()
    with caplog.at_level(logging.WARNING, logger="msa_slam.datasets"):
        result = _command("run", tmp_path, "-p", "window=4", frames=12)  # MSA: a window to check
    assert result.exit_code == 0, result.output
    scans = tmp_path / "scans"
    assert opened == [str(scans)] and (tmp_path / "out" / "report.md").is_file()
    assert [r.getMessage() for r in caplog.records if "no timestamps" in r.getMessage()] == [
        f"{scans}: the scans have no timestamps (no times.txt or TUM ground truth); taking frame k to be at k s "
        "(1 frame/s)"
    ]


def test_compare_opens_its_dataset_once_for_all_its_methods(tmp_path, monkeypatch):
    opened = _counting_opens(monkeypatch)
    result = _command("compare", tmp_path, "--no-sweep", "--first", "1", frames=24)  # enough for 3 keyframes each
    assert result.exit_code == 0, result.output
    assert opened == [str(tmp_path / "scans")]
    report = (tmp_path / "out" / "report.md").read_text()
    assert report.startswith("# Sampler comparison on scans\n")
    assert f"Dataset `{tmp_path / 'scans'}` (sequence scans), from scan 1 (--first 1): 23 frames." in report


def test_the_library_checks_the_window_before_the_front_end(tmp_path, monkeypatch):
    """run and run_compare refuse a window that never fills before any odometry, as the commands do."""

    def no_odometry(*args, **kwargs):
        raise AssertionError("the odometry ran before the window check")

    monkeypatch.setattr("msa_slam.pipeline.read_ahead.sequence_odometry", no_odometry)
    config = _config(tmp_path, sampler="msa", flush=False)
    expected = (
        f"sampler 'msa': window=10 is longer than the {FRAMES} frames read, so it never fills and only frame "
        "0 becomes a keyframe (flush is off); the evaluation needs at least 3: "
        + CONFIG_WINDOW_FIX.format(frames=FRAMES, window=10)
    )
    with pytest.raises(InputError) as err:
        run(config)
    assert str(err.value) == expected
    with pytest.raises(InputError) as err:  # every method's window is checked, not only the first one's
        run_compare(config, tmp_path / "out", methods=(("all", "all", {}), ("msa", "msa", {})))
    assert str(err.value) == expected and not (tmp_path / "out").exists()


def test_a_window_check_with_flush_only_warns(tmp_path):
    config = _config(tmp_path, sampler="msa")
    with pytest.warns(UserWarning, match=f"window=10 is longer than the stream \\({FRAMES} frames\\)"):
        frontend = prepare_frontend(config)
    assert len(frontend) == FRAMES


# Scan 0 is not read when the dataset is opened: the first scan of the selection is.


def _damaged_first(tmp_path: Path, damage: str) -> Path:
    folder, _ = _untimed_folder(tmp_path)
    scan0 = folder / "000000.bin"
    if damage == "truncated":
        scan0.write_bytes(scan0.read_bytes()[:20])
    else:  # float64 records: a whole number of 16-byte points, but no LiDAR's coordinates
        np.random.default_rng(0).normal(size=(50, 4)).astype(np.float64).__mul__(1e6).tofile(scan0)
    return folder


@pytest.mark.parametrize(
    ("damage", "error"),
    [
        ("truncated", "20 bytes is not a whole number of 16-byte (x, y, z, r) float32 points"),
        ("garbage", "coordinate "),
    ],
)
def test_a_damaged_scan_0_stops_only_a_run_that_reads_it(tmp_path, damage, error):
    folder = _damaged_first(tmp_path, damage)
    later = open_sequence(str(folder), source=SourceOptions(first=1))
    assert [frame.index for frame in later] == list(range(FRAMES - 1))
    np.testing.assert_array_equal(later[0].points, _points(1))
    assert not later.point_times
    with pytest.raises(InputError) as err:
        open_sequence(str(folder))
    message = str(err.value)
    assert message.startswith(f"{folder / '000000.bin'}: {error}") and "\n" not in message
    assert len(open_dataset(folder)) == FRAMES  # opening alone reads no scan


def test_point_times_are_known_from_the_first_selected_scan(tmp_path):
    assert open_dataset(_kitti(tmp_path / "kitti")).select(first=2).point_times  # derived from azimuth
    folder, _ = _untimed_folder(tmp_path)
    assert not open_dataset(folder).select().point_times


# Deskew without per-point times: switched off once, where the odometry is made


def test_deskew_without_point_times_is_switched_off_where_the_odometry_is_made(tmp_path, caplog):
    scans, _ = _untimed_folder(tmp_path)
    params = {"max_range": 30.0, "deskew": True}
    config = make_config(
        dataset=str(scans), mode="realistic", sampler="all", odometry_params=params, cache_dir=str(tmp_path / "cache")
    )
    for fresh in (True, False):  # computed, then from the cache: both warn once and record deskew off
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="msa_slam.odometry"):
            frontend = prepare_frontend(config)
        assert frontend.cached["odometry"] is not fresh
        assert frontend.odometry_effective["data"]["deskew"] is False
        assert [r.getMessage() for r in caplog.records if r.name.startswith("msa_slam.odometry")] == [NO_POINT_TIMES]
    off = prepare_frontend(config.model_copy(update={"odometry_params": {"max_range": 30.0}}))
    assert off.cached["odometry"]  # the cache key is that of the deskew actually done (off)
    np.testing.assert_array_equal(off.odometry, frontend.odometry)


def test_online_odometry_is_made_without_deskew_for_a_source_without_point_times(caplog):
    config = make_online_config(dataset=COARSE, odometry="kiss", odometry_params={"max_range": 30.0, "deskew": True})
    source = _coarse(FRAMES)  # simulated in memory: frames without per-point times
    with caplog.at_level(logging.WARNING, logger="msa_slam.odometry"):
        odometry, cached = make_online_odometry(config, source, FRAMES)
    assert odometry.config["data"]["deskew"] is False and not cached
    assert [r.getMessage() for r in caplog.records] == [NO_POINT_TIMES]
    for told in (True, None):  # frames with per-point times, or a source that does not say: deskew as configured
        other = FrameSource("timed", source.gt_poses, source.frames, point_times=told)
        assert make_online_odometry(config, other, FRAMES)[0].config["data"]["deskew"] is True


def test_kiss_odometry_refuses_deskew_on_a_scan_without_point_times():
    odometry = KissOdometry(max_range=30.0, deskew=True)
    with pytest.raises(InputError, match=r"^odometry frame 0: deskew is on but the scan has no per-point times"):
        odometry.register(_points(0), None, 0.0)
    odometry.without_point_times()
    odometry.register(_points(0), None, 0.0)


# The online progress line


def test_online_progress_counts_the_accepted_loops(capsys):
    config = make_online_config(
        dataset=COARSE,
        odometry="gt-noise",
        sampler="all",
        min_frame_gap=20,
        odometry_params={"translation_noise": 0.02, "rotation_noise_deg": 0.1},
    )
    result = run(config, quiet=False)
    accepted = sum(c.accepted for c in result.loops)
    done = [line for line in capsys.readouterr().err.splitlines() if line.startswith(f"online {config.name}: done")]
    assert accepted > 0 and len(done) == 1 and done[0].endswith(f"loops {accepted}")


def test_a_seeds_comparison_refused_once_the_data_is_open_leaves_no_folder(tmp_path):
    """compare --seeds creates its folder to grow it in place; a window refused on seed 0 removes it again
    (with the `latest` link, for a timestamped folder), as nothing was written into it, and the default parent
    it made for it, left empty."""
    config = make_config(
        dataset="sim:test", sampler="msa", flush=False, cache_dir=str(tmp_path / "cache"), source={"frames": 5}
    )
    methods = (("all", "all", {}), ("msa", "msa", {}))
    for out in (tmp_path / "out", None):
        with pytest.raises(InputError, match="window=10 is longer than the 5 frames read"):
            run_compare(config, out, methods=methods, seeds=[0, 1], default_parent=tmp_path / "results")
    assert not (tmp_path / "out").exists() and not (tmp_path / "results").exists()
