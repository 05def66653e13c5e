"""Times of real recordings (QA of own recordings): per-point time files in the cache key, scans without
timestamps (warned, not used as a frame rate or sweep interval), deskew without per-point times (warned and
recorded as off), and the online progress line's figures."""

from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers.metrics import metrics_json
from helpers.scans import write_bin

from msa_slam.datasets import Frame, open_dataset
from msa_slam.errors import InputError
from msa_slam.io.cache import sequence_identity
from msa_slam.odometry import KissOdometry, OdometryCache, sequence_odometry
from msa_slam.odometry.choice import make_odometry
from msa_slam.pipeline import LiveFrontEnd, run
from msa_slam.pipeline.config import NO_TIMESTAMPS, make_config, make_online_config
from msa_slam.pipeline.live import frame_rate_hz
from msa_slam.reporting.report import _online_lines as online_report_lines
from msa_slam.sources import open_source
from msa_slam.types import FrameSource

N = 6
COARSE = "live:figure-eight,stride=4,azimuth_steps=180,realism=clean"


def _points(k: int, n: int = 400) -> np.ndarray:
    """A box-shaped room seen from a sensor moving 0.2 m a scan along x (enough structure for KISS-ICP)."""
    rng = np.random.default_rng(k)
    walls = rng.uniform(-10, 10, (n, 3))
    walls[: n // 2, 1] = np.where(rng.random(n // 2) < 0.5, -6.0, 6.0)
    walls[n // 2 :, 0] = np.where(rng.random(n - n // 2) < 0.5, -10.0, 10.0)
    walls[:, 0] -= 0.2 * k
    return walls.astype(np.float32)


def _kitti(root: Path, times: bool = True, point_times: bool = False) -> Path:
    for k in range(N):
        write_bin(root / "velodyne" / f"{k:06d}.bin", _points(k))
        if point_times:
            (root / "velodyne_times").mkdir(exist_ok=True)
            np.save(root / "velodyne_times" / f"{k:06d}.npy", np.linspace(0, 0.1, 400, dtype=np.float32))
    if times:
        (root / "times.txt").write_text("".join(f"{0.1 * k:.6f}\n" for k in range(N)))
    return root


def test_per_point_time_files_are_part_of_the_cache_key(tmp_path):
    """velodyne_times/*.npy rewritten beside the same scans must not reuse odometry deskewed with the old ones."""
    seq = _kitti(tmp_path / "a", point_times=True)
    config = KissOdometry(deskew=True).config
    key = OdometryCache.key(open_dataset(seq), config)
    identity = sequence_identity(open_dataset(seq).select(count=2))
    assert [entry[0] for entry in identity[:4]] == [
        "velodyne/000000.bin",
        "velodyne/000001.bin",
        "velodyne_times/000000.npy",
        "velodyne_times/000001.npy",
    ]
    shutil.copytree(seq, tmp_path / "b")  # copy2: same sizes and times, elsewhere
    assert OdometryCache.key(open_dataset(tmp_path / "b"), config) == key
    times_file = seq / "velodyne_times" / "000003.npy"
    np.save(times_file, np.linspace(0, 0.05, 400, dtype=np.float32))
    os.utime(times_file, ns=(1, 1))
    assert OdometryCache.key(open_dataset(seq), config) != key


def test_scans_without_timestamps_are_marked_and_warned_once(tmp_path, caplog):
    untimed = _kitti(tmp_path / "untimed", times=False)
    with caplog.at_level(logging.WARNING, logger="msa_slam.datasets"):
        first = open_dataset(untimed).select()
        open_dataset(untimed).select(count=3)  # the next cell of an experiment grid opens it again
        timed = open_dataset(_kitti(tmp_path / "timed")).select()
    assert not first.times_known and timed.times_known
    assert not open_source(str(untimed)).times_known and open_source(str(tmp_path / "timed")).times_known
    np.testing.assert_array_equal(first.times, np.arange(N))
    warnings = [r.getMessage() for r in caplog.records]
    assert warnings == [
        f"{untimed}: the scans have no timestamps (no times.txt or TUM ground truth); taking frame "
        "k to be at k s (1 frame/s)"
    ]


class _TimeRecorder:
    """An odometry that records the scan times it is given."""

    config = {"method": "recorder"}

    def __init__(self) -> None:
        self.times: list[float | None] = []

    def register(self, points, timestamps=None, time=None) -> np.ndarray:
        self.times.append(time)
        return np.eye(4)


def test_odometry_gets_no_scan_times_when_the_scans_have_none(tmp_path):
    """Frame numbers as times would make a sweep 0.1 of a frame interval, so deskewing corrected 10 % of the motion."""
    for name, times, expected in (("timed", True, list(0.1 * np.arange(N))), ("untimed", False, [None] * N)):
        odometry = _TimeRecorder()
        sequence_odometry(open_dataset(_kitti(tmp_path / name, times=times)), odometry)
        assert odometry.times == pytest.approx(expected) if times else odometry.times == expected


def test_deskew_without_per_point_times_is_warned_and_recorded_off(tmp_path, caplog):
    """A folder of .bin scans has no per-point times: deskew=true did nothing while metrics.json said true."""
    folder = tmp_path / "scans"
    for k in range(N):
        write_bin(folder / f"{k}.bin", _points(k))
    cache = OdometryCache(tmp_path / "cache")
    config = make_config(dataset=str(folder), odometry_params={"max_range": 30.0, "deskew": True})
    for fresh in (True, False):  # computed, then from the cache: both warn and record what was done
        sequence = open_dataset(folder).select()  # warns once that the scans have no timestamps
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="msa_slam.odometry"):
            odometry = make_odometry(config, len(sequence), sequence.point_times)
            poses, from_cache, _ = sequence_odometry(sequence, odometry, cache, quiet=True)
        assert from_cache is not fresh and odometry.config["data"]["deskew"] is False
        assert [r.getMessage() for r in caplog.records] == [
            "odometry: no per-point times: deskewing has no effect (recorded as deskew false)"
        ]
    assert sequence_odometry(open_dataset(folder), KissOdometry(max_range=30.0), cache, quiet=True)[1]  # same entry
    fresh, _, _ = sequence_odometry(open_dataset(folder), KissOdometry(max_range=30.0), quiet=True)
    np.testing.assert_array_equal(poses, fresh)
    timed = KissOdometry(max_range=30.0, deskew=True)  # a KITTI layout: times derived from azimuth
    sequence_odometry(open_dataset(_kitti(tmp_path / "kitti")), timed, quiet=True)
    assert timed.config["data"]["deskew"] is True


def test_real_time_factor_uses_the_sensor_rate_when_frames_have_no_timestamps(caplog):
    assert frame_rate_hz(0.0, 11.0, 12, 10.0) == (1.0, "timestamps")
    assert frame_rate_hz(0.0, 11.0, 12, 10.0, times_known=False) == (10.0, NO_TIMESTAMPS)
    scans = [f for _, f in zip(range(30), open_source(COARSE).frames())]
    gt = np.stack([s.gt_pose for s in scans])
    source = FrameSource(
        "untimed", gt, lambda: (Frame(i, float(i), s.points, s.gt_pose) for i, s in enumerate(scans)), times_known=False
    )
    cfg = make_online_config(
        dataset=COARSE, odometry="gt-noise", sampler="constant", sampler_params={"distance": 1.0}, sensor_rate_hz=20.0
    )
    with caplog.at_level(logging.WARNING, logger="msa_slam.pipeline.live"):
        result = run(cfg, LiveFrontEnd(source))
    metrics = metrics_json(result)
    assert metrics["frame_rate_hz"] == 20.0 and metrics["frame_rate_from"] == NO_TIMESTAMPS
    assert "over the data's 20.0 frames/s (the config's sensor_rate_hz: the frames have no timestamps)" in "\n".join(
        online_report_lines(result)
    )
    assert metrics["realtime_factor"] == pytest.approx(metrics["fps"] / 20.0)
    assert (
        "the frames have no timestamps; the real-time factor is taken against the config's sensor_rate_hz "
        "(20 Hz)" in caplog.text
    )


def _coarse(n: int, fail_at: int | None = None) -> FrameSource:
    scans = [f for _, f in zip(range(n), open_source(COARSE).frames())]

    def frames():
        for i, scan in enumerate(scans):
            if i == fail_at:
                raise InputError(f"frame {i}: unreadable")
            yield Frame(i, 0.1 * i, scan.points, scan.gt_pose)

    return FrameSource("coarse", np.stack([s.gt_pose for s in scans]), frames, point_times=False)


def test_online_progress_stops_at_the_failing_frame(capsys):
    cfg = make_online_config(dataset=COARSE, odometry="gt-noise", sampler="constant", sampler_params={"distance": 1.0})
    with pytest.raises(InputError, match="frame 7: unreadable"):
        run(cfg, LiveFrontEnd(_coarse(12, fail_at=7)), quiet=False)
    assert f"online {cfg.name}: stopped at 7/12" in capsys.readouterr().err


def test_online_progress_counts_the_keyframes_the_flush_adds(capsys):
    cfg = make_online_config(dataset=COARSE, odometry="gt-noise", sampler="msa", sampler_params={"window": 10})
    result = run(cfg, LiveFrontEnd(_coarse(25)), quiet=False)
    assert metrics_json(result)["sampler_stats"]["flushed_keyframes"] > 0
    done = [line for line in capsys.readouterr().err.splitlines() if line.startswith(f"online {cfg.name}: done")]
    assert len(done) == 1 and f"kf {len(result.keyframes)} " in done[0]
