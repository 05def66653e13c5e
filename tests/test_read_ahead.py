"""The batch front end reads, describes and downsamples the scans in a second thread while the odometry registers:
same poses, descriptors, frame clouds and cache entries as the stages run one after the other, each scan read once
a run; the reader stays a bounded number of frames ahead, its errors are raised at their frame, and it stops when
the consumer stops. The online pipeline has a live source's frames simulated ahead the same way."""

from __future__ import annotations

import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from msa_slam.datasets import Frame, ScanSequence
from msa_slam.descriptors import make_descriptor
from msa_slam.descriptors.cache import compute_descriptors, descriptor_key
from msa_slam.errors import InputError
from msa_slam.io.cache import TIMES_PREFIX, CacheDir
from msa_slam.odometry import OdometryCache, sequence_odometry
from msa_slam.odometry.choice import make_odometry
from msa_slam.pipeline import LiveFrontEnd, make_config, prepare_frontend, run
from msa_slam.pipeline.config import make_online_config
from msa_slam.pipeline.read_ahead import DEPTH, ReadAhead
from msa_slam.registration import downsample
from msa_slam.sources import open_sequence, open_source


def _entries(folder: Path, clouds: bool = True) -> dict[str, bytes]:
    """The cache's entries by name (the frame clouds' unless not `clouds`), without the per-frame compute times
    (wall clock) and the digest memo."""
    return {
        p.name: p.read_bytes()
        for p in sorted(folder.glob("*.npy"))
        if not p.name.startswith(TIMES_PREFIX) and (clouds or not p.name.startswith("frame-cloud"))
    }


def test_one_pass_gives_the_stages_results_and_cache_entries(sequence, tmp_path):
    config = make_config(dataset=str(sequence), source={"frames": 40}, cache_dir=str(tmp_path / "pass"))
    frontend = prepare_frontend(config)
    assert frontend.cached == {"odometry": False, "descriptors": False, "clouds": False}
    assert set(frontend.timer.seconds) == {"dataset", "odometry", "descriptors", "clouds"}

    scans = open_sequence(str(sequence), source=config.source)  # the stages one after the other, as before
    cache = CacheDir(tmp_path / "apart" / "pipeline")
    odometry = make_odometry(config, len(scans), scans.point_times)
    poses = sequence_odometry(scans, odometry, OdometryCache(cache), quiet=True)
    key = descriptor_key(scans, config.descriptor, config.descriptor_params, cache)
    descriptors = compute_descriptors(scans, make_descriptor(config.descriptor), cache, key)

    assert np.array_equal(frontend.odometry, poses.values) and np.array_equal(frontend.descriptors, descriptors.values)
    clouds = [downsample(scans[i].points, config.verifier.voxel_size) for i in range(len(scans))]
    assert np.array_equal(frontend.clouds.points, np.concatenate(clouds))
    assert np.array_equal(np.diff(frontend.clouds.offsets), [len(c) for c in clouds])
    one_pass = _entries(tmp_path / "pass" / "pipeline")
    assert len(one_pass) == 5 and sum(name.startswith("frame-cloud") for name in one_pass) == 2
    # poses, their unregistered frames, descriptors: those of the stages apart
    assert _entries(tmp_path / "pass" / "pipeline", clouds=False) == _entries(tmp_path / "apart" / "pipeline")
    again = prepare_frontend(config)  # the entries written in one pass are read back
    assert again.cached == {"odometry": True, "descriptors": True, "clouds": True}
    assert np.array_equal(again.descriptors, frontend.descriptors)
    for stage, seconds in again.replayed_s.items():  # computed alongside, the descriptors still count their time
        assert 0 < seconds <= frontend.timer.seconds[stage]


def test_a_cold_front_end_reads_each_scan_once(sequence, tmp_path, monkeypatch):
    reads: dict[str, int] = {}
    original = ScanSequence._read

    def counted(self, path, *args, **kwargs):
        reads[str(path)] = reads.get(str(path), 0) + 1
        return original(self, path, *args, **kwargs)

    monkeypatch.setattr(ScanSequence, "_read", counted)
    config = make_config(dataset=str(sequence), source={"frames": 30}, cache_dir=str(tmp_path))
    opened = open_sequence(str(sequence), source=config.source)
    opening = dict(reads)  # opening checks the scans selected and reads the first
    reads.clear()
    frontend = prepare_frontend(config)
    assert not any(frontend.cached.values()) and "clouds" in frontend.cached
    assert reads == {str(scan): 1 + opening.get(str(scan), 0) for scan in opened.scan_files}


def test_the_stages_missing_beside_a_cached_odometry_are_computed_in_a_pass_that_only_reads(sequence, tmp_path):
    config = make_config(dataset=str(sequence), source={"frames": 30}, cache_dir=str(tmp_path))
    first = prepare_frontend(config)
    for entry in (tmp_path / "pipeline").glob("*.npy"):
        if entry.name.startswith(("descriptors-", "frame-cloud")):
            entry.unlink()
    again = prepare_frontend(config)
    assert again.cached == {"odometry": True, "descriptors": False, "clouds": False}
    assert np.array_equal(again.descriptors, first.descriptors)
    assert np.array_equal(again.clouds.points, first.clouds.points)


class _Scans:
    """A sequence of `n` tiny scans that records how far ahead of the consumer it is read and can fail at a frame."""

    def __init__(self, n: int, fail_at: int | None = None) -> None:
        self.n, self.fail_at, self.consumed, self.ahead, self.last = n, fail_at, 0, 0, -1
        self.reader: threading.Thread | None = None

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> Frame:
        self.reader = threading.current_thread()
        self.ahead, self.last = max(self.ahead, i - self.consumed), i
        if i == self.fail_at:
            raise InputError(f"scan {i}: unreadable")
        return Frame(i, 0.1 * i, np.full((5, 3), float(i)), None)


def test_reader_stays_a_bounded_number_of_frames_ahead_and_describes_in_order():
    scans = _Scans(30)
    ahead = ReadAhead(scans, make_descriptor("sc"))
    for i, frame in enumerate(ahead):
        assert frame.index == i
        scans.consumed = i + 1
    # DEPTH frames in the queue and the one being read: never more
    assert 0 < scans.ahead <= DEPTH + 1 and scans.reader is not threading.current_thread()
    described = ahead.described()
    expected = np.stack([make_descriptor("sc").compute(np.full((5, 3), float(i)), frame=i) for i in range(30)])
    assert np.array_equal(described.values, expected) and described.ms.shape == (30,)


def test_reader_error_is_raised_at_its_frame():
    seen = []
    with pytest.raises(InputError, match="^scan 7: unreadable$"):
        for frame in ReadAhead(_Scans(30, fail_at=7)):
            seen.append(frame.index)
    assert seen == list(range(7))


def test_reader_stops_when_the_consumer_stops():
    scans = _Scans(1000)
    ahead = ReadAhead(scans)
    for frame in ahead:  # the loop's generator is closed when it ends: it joins its reader
        if frame.index == 3:
            break
    assert scans.reader is not None and not scans.reader.is_alive()
    assert scans.last <= 3 + DEPTH + 1 and not ahead.complete
    with pytest.raises(RuntimeError, match="not all read"):
        ahead.described()


@pytest.mark.parametrize("live", [True, False])
def test_a_live_sources_frames_are_simulated_ahead_by_a_thread_of_their_own(live):
    """A sensor's frames come while the previous ones are processed: a live source's are made by another thread,
    no further than the frames the run reads; recorded frames are read by the run's thread, as they were."""
    source = open_source("live:figure-eight,stride=4,azimuth_steps=180,realism=clean")
    makers: list[threading.Thread] = []

    def frames():
        for frame in source.frames():
            makers.append(threading.current_thread())
            yield frame

    config = make_online_config(dataset=source.name, odometry="gt-noise", sampler="all", max_frames=12)
    result = run(config, LiveFrontEnd(replace(source, frames=frames, live=live)))
    assert len(result) == 12 and len(makers) == 12
    assert all((maker is threading.current_thread()) != live for maker in makers)
