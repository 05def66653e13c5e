"""The batch front end reads, describes and downsamples the scans in a forked process (or a thread, where the
sequence cannot be read from a fork) while the odometry registers: same poses, descriptors, frame clouds and cache
entries as the stages run one after the other, each scan read once a run; the reader stays a bounded number of
frames ahead, its errors are raised at their frame, and it is gone when the consumer stops. The online pipeline has a live source's frames simulated ahead by a spawned process."""

from __future__ import annotations

import contextlib
import copy
import multiprocessing
import os
import threading
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from msa_slam.datasets import Frame, ScanSequence
from msa_slam.datasets.options import SourceOptions
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
from msa_slam.sim import config as sim_config
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
    log = tmp_path / "reads.log"  # appended to by whichever process reads (the reader is forked)
    original = ScanSequence._read

    def counted(self, path, *args, **kwargs):
        with log.open("a") as out:
            out.write(f"{path}\n")
        return original(self, path, *args, **kwargs)

    def reads() -> dict[str, int]:
        lines = log.read_text().splitlines() if log.exists() else []
        log.unlink(missing_ok=True)
        return {line: lines.count(line) for line in set(lines)}

    monkeypatch.setattr(ScanSequence, "_read", counted)
    config = make_config(dataset=str(sequence), source={"frames": 30}, cache_dir=str(tmp_path / "cache"))
    opened = open_sequence(str(sequence), source=config.source)
    opening = reads()  # opening checks the scans selected and reads the first
    frontend = prepare_frontend(config)
    assert not any(frontend.cached.values()) and "clouds" in frontend.cached
    assert reads() == {str(scan): 1 + opening.get(str(scan), 0) for scan in opened.scan_files}


def test_a_forked_reader_gives_what_a_reader_thread_gives(sequence):
    """The reader runs in a process forked for the pass when the sequence allows it (scans read from their own
    files); the frames, descriptors, clouds and their order are those a thread reads."""
    forked = open_sequence(str(sequence), source=SourceOptions(frames=12))
    threaded = copy.copy(forked)
    threaded.forkable = False
    assert forked.forkable
    results = []
    for scans in (forked, threaded):
        ahead = ReadAhead(scans, make_descriptor("sc"), voxel_size=0.5)
        frames = list(ahead)
        results.append((frames, ahead.described().values, ahead.downsampled()[0]))
    (frames, described, clouds), (frames_t, described_t, clouds_t) = results
    assert [f.index for f in frames] == [f.index for f in frames_t] == list(range(12))
    for a, b in zip(frames, frames_t, strict=True):
        assert np.array_equal(a.points, b.points) and np.array_equal(a.timestamps, b.timestamps) and a.time == b.time
    assert np.array_equal(described, described_t)
    assert all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(clouds, clouds_t, strict=True))
    assert not multiprocessing.active_children()


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
    """A sequence of `n` tiny scans that records (in memory shared with a forked reader) how far ahead of the
    consumer it is read and by which process, and can fail at a frame, with an error that pickles or not, or end
    the reading process there."""

    def __init__(
        self, n: int, forkable: bool, fail_at: int | None = None, error: type = InputError, die_at: int | None = None
    ) -> None:
        self.n, self.forkable, self.fail_at, self.error, self.die_at = n, forkable, fail_at, error, die_at
        context = multiprocessing.get_context("fork")
        self._consumed, self._ahead, self._last = (context.Value("q", v) for v in (0, 0, -1))
        self._pid, self._thread = context.Value("q", 0), context.Value("q", 0)

    consumed = property(lambda self: self._consumed.value, lambda self, v: setattr(self._consumed, "value", v))
    ahead = property(lambda self: self._ahead.value)
    last = property(lambda self: self._last.value)
    reader = property(lambda self: (self._pid.value, self._thread.value))  # the process and thread that read

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> Frame:
        self._pid.value, self._thread.value = os.getpid(), threading.get_ident()
        self._ahead.value, self._last.value = max(self._ahead.value, i - self._consumed.value), i
        if i == self.die_at:
            os._exit(3)
        if i == self.fail_at:
            raise self.error(f"scan {i}: unreadable")
        return Frame(i, 0.1 * i, np.full((5, 3), float(i)), None)


class _Unpicklable(Exception):
    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.retry = lambda: None  # a lambda does not pickle


BOTH = pytest.mark.parametrize("forkable", [True, False], ids=["process", "thread"])


@BOTH
def test_reader_stays_a_bounded_number_of_frames_ahead_and_describes_in_order(forkable):
    scans = _Scans(30, forkable)
    ahead = ReadAhead(scans, make_descriptor("sc"))
    for i, frame in enumerate(ahead):
        assert frame.index == i
        scans.consumed = i + 1
    # DEPTH frames in the queue and the one being read: never more
    assert 0 < scans.ahead <= DEPTH + 1
    pid, thread = scans.reader
    assert (pid != os.getpid()) == forkable and (pid, thread) != (os.getpid(), threading.get_ident())
    described = ahead.described()
    expected = np.stack([make_descriptor("sc").compute(np.full((5, 3), float(i)), frame=i) for i in range(30)])
    assert np.array_equal(described.values, expected) and described.ms.shape == (30,)


@BOTH
def test_reader_error_is_raised_at_its_frame(forkable):
    seen = []
    with pytest.raises(InputError, match="^scan 7: unreadable$"):
        for frame in ReadAhead(_Scans(30, forkable, fail_at=7)):
            seen.append(frame.index)
    assert seen == list(range(7)) and not multiprocessing.active_children()


def test_a_forked_readers_error_that_cannot_be_pickled_is_still_raised_at_its_frame():
    seen = []
    with pytest.raises(RuntimeError, match="^_Unpicklable: scan 4: unreadable\nin the front end's reader process"):
        for frame in ReadAhead(_Scans(30, True, fail_at=4, error=_Unpicklable)):
            seen.append(frame.index)
    assert seen == list(range(4))


def test_a_forked_reader_that_dies_is_an_error_not_a_hang():
    seen = []
    with pytest.raises(RuntimeError, match=r"reader process ended \(exit code 3\) before its last frame"):
        for frame in ReadAhead(_Scans(30, True, die_at=5)):
            seen.append(frame.index)
    # the frames it sent before it died, in order (those it had not yet written out are lost with it)
    assert seen == list(range(len(seen))) and len(seen) <= 5 and not multiprocessing.active_children()


def _read_in_a_daemon(results) -> None:
    scans = _Scans(10, True)
    try:
        results.put(([frame.index for frame in ReadAhead(scans)], scans.reader[0] == os.getpid()))
    except Exception as exc:  # e.g. "daemonic processes are not allowed to have children"
        results.put((repr(exc), None))


def test_a_daemonic_process_reads_in_a_thread():
    """A daemonic process (a Dask worker running an experiment's cell) may not have children: its reader is a
    thread."""
    context = multiprocessing.get_context("fork")
    results = context.Queue()
    daemon = context.Process(target=_read_in_a_daemon, args=(results,), daemon=True)
    daemon.start()
    indices, in_the_daemon = results.get(timeout=60)
    daemon.join()
    assert indices == list(range(10)) and in_the_daemon and daemon.exitcode == 0


@BOTH
@pytest.mark.parametrize("stop", [StopIteration, KeyboardInterrupt])
def test_reader_stops_when_the_consumer_stops(forkable, stop):
    """A consumer that breaks off, or is interrupted (Ctrl-C), leaves no reader running."""
    scans = _Scans(1000, forkable)
    ahead = ReadAhead(scans)
    threads = threading.active_count()
    with contextlib.suppress(KeyboardInterrupt):
        for frame in ahead:  # the loop's generator is closed when it ends: it ends its reader
            if frame.index == 3:
                if stop is KeyboardInterrupt:
                    raise KeyboardInterrupt
                break
    assert not multiprocessing.active_children() and threading.active_count() <= threads
    last = scans.last
    assert last <= 3 + DEPTH + 1 and not ahead.complete
    with pytest.raises(RuntimeError, match="not all read"):
        ahead.described()
    assert scans.last == last  # nothing reads on


def _logged(producer, log: Path):
    """`producer`'s frames, each logged to `log` with the process that made it (pickled to a spawned process)."""
    for frame in producer():
        with log.open("a") as f:
            f.write(f"{os.getpid()}\n")
        yield frame


def test_a_live_sources_frames_are_simulated_ahead_by_a_process_of_their_own(tmp_path, monkeypatch):
    """A sensor's frames come while the previous ones are processed: a live source's are made by a spawned
    process (KISS-ICP holds the GIL while it registers, so a thread would simulate little beside it), no further
    than a few frames ahead of the run, and the run is the one it is with the frames made in its own process."""
    monkeypatch.setattr(sim_config, "PARALLEL_MIN_FRAMES", 12)  # a run this long is worth a process
    source = open_source("live:figure-eight,stride=4,azimuth_steps=180,realism=clean")
    log = tmp_path / "makers.txt"
    config = make_online_config(dataset=source.name, odometry="gt-noise", sampler="all", max_frames=12)
    spawned = run(config, LiveFrontEnd(replace(source, producer=partial(_logged, source.producer, log))))
    makers = [int(line) for line in log.read_text().split()]
    assert 12 <= len(makers) <= 12 + DEPTH + 1  # the queue's frames and the one waiting to be put
    assert len(set(makers)) == 1 and makers[0] != os.getpid()
    here = run(config, LiveFrontEnd(replace(source, live=False)))
    assert len(spawned) == len(here) == 12
    np.testing.assert_array_equal(spawned.odometry, here.odometry)
    np.testing.assert_array_equal(spawned.optimised, here.optimised)
    np.testing.assert_array_equal(spawned.keyframes, here.keyframes)


@pytest.mark.parametrize("live", [True, False])
def test_a_short_live_run_has_its_frames_made_by_a_thread(live):
    """A live run too short to pay a process's start-up (fewer than PARALLEL_MIN_FRAMES frames) has its frames
    made by another thread; recorded frames are read by the run's thread, as they were."""
    source = open_source("live:figure-eight,stride=4,azimuth_steps=180,realism=clean")
    makers: list[threading.Thread] = []

    def frames():
        for frame in source.frames():
            makers.append(threading.current_thread())
            yield frame

    config = make_online_config(dataset=source.name, odometry="gt-noise", sampler="all", max_frames=12)
    assert config.max_frames < sim_config.PARALLEL_MIN_FRAMES
    result = run(config, LiveFrontEnd(replace(source, frames=frames, live=live)))
    assert len(result) == 12 and len(makers) >= 12
    assert all((maker is threading.current_thread()) != live for maker in makers)
