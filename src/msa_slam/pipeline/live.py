"""The live front end of the paper's online experiment (section V-B, Table II): frames one by one, as on a robot
(LiveFrontEnd, which pipeline.driver.run drives).

Each frame: odometry -> descriptor -> the SLAM core (msa_slam.slam: sampler, keyframe store with clouds in
RAM or on disk, loop candidates, verification, and an iSAM2 graph (Kaess et al., IJRR 2012) updated at
every frame that finalised keyframes). A recorder keeps, per frame, the time of each step and the memory
held (keyframe clouds, descriptors, graph, pending scans, process RSS); at the end F1-max, ATE before and
after optimisation, and throughput (frames per second, real-time factor for the sensor rate). The odometry
gets the batch pipeline's plausibility checks (stalled, implausible steps) once the run has ended.

Throughput is that of the whole pipeline as it ran (reading the frames included; a live source's frames are
simulated by a process of their own a few frames ahead, as a sensor's driver delivers them while the previous ones
are processed: arriving); odometry replayed from the cache counts with the time it took when it was computed, and the run says it was replayed. The progress line,
metrics.json and report.md compute frames per second and real-time factor with one function
(evaluation.resources.throughput) from the same seconds.

KISS-ICP runs on every core for a live source (frames streamed once, as from a sensor, where single-threaded
odometry is most of a run's time: docs/performance.md) and on one thread for recorded data, whose replay stays
bit-reproducible; odometry.num_threads, when given, wins (with_odometry_threads). The count is in the progress
label, metrics.json (`threads`) and report.md.
"""

from __future__ import annotations

import logging
import multiprocessing
import time
from collections.abc import Callable, Generator
from contextlib import closing
from dataclasses import replace
from itertools import islice
from typing import Protocol, TypedDict

import numpy as np

from msa_slam.datasets import Frame
from msa_slam.descriptors import make_descriptor
from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import ONLINE, Latency, ProtocolRecord, RunSetup, Throughput, Timing
from msa_slam.evaluation.resources import current_rss_bytes, throughput
from msa_slam.evaluation.sanity import frontend_warnings
from msa_slam.io.cache import CacheDir, pipeline_cache
from msa_slam.odometry import KissOdometry, NoisyOdometry, OdometryCache, ReplayedOdometry
from msa_slam.odometry.cache import register_frames
from msa_slam.odometry.choice import make_odometry
from msa_slam.odometry.kiss import DEFAULT_THREADS
from msa_slam.pipeline.config import NO_TIMESTAMPS, NOT_REPRODUCIBLE, OnlineConfig, RunConfig
from msa_slam.pipeline.forked_ahead import spawned_ahead
from msa_slam.pipeline.frontend import CONFIG_WINDOW_FIX, check_window, config_as_run, deskew_record, source_warnings
from msa_slam.pipeline.read_ahead import DEPTH, ahead
from msa_slam.progress import LogProgress, Progress, progress_bar
from msa_slam.slam import BACKEND_STEPS, RunResult, SlamBackend
from msa_slam.sources import open_source
from msa_slam.types import FrameSource
from msa_slam.viz.labels import counted as noun_count  # `counted`: the stream's loop tally
from msa_slam.workers import available_cpus

logger = logging.getLogger(__name__)

STEPS = ("odometry", "descriptor", *BACKEND_STEPS)
MEMORY = (
    "keyframes",
    "cloud_bytes",
    "cloud_disk_bytes",
    "descriptor_bytes",
    "graph_bytes",
    "record_bytes",
    "pending_bytes",
    "rss_bytes",
)


class MemoryRecorder:
    """Per-frame memory series of an online run (the paper's Fig. 7): accounted bytes and process RSS."""

    def __init__(self, n_frames: int) -> None:
        self.memory = {m: np.zeros(n_frames, dtype=np.int64) for m in MEMORY}

    def record(self, backend: SlamBackend, frame: int) -> None:
        mem, accounted = self.memory, backend.memory_bytes()
        mem["keyframes"][frame] = len(backend.store)
        for key, value in accounted.items():  # local_map_bytes only with a local-map loop detector
            mem.setdefault(key, np.zeros(len(mem["keyframes"]), dtype=np.int64))[frame] = value
        mem["pending_bytes"][frame] = backend.pending_bytes
        mem["rss_bytes"][frame] = current_rss_bytes()


def _percentiles(values: np.ndarray) -> Latency:
    v = np.asarray(values, dtype=np.float64)
    if not v.size:
        return Latency(0.0, 0.0, 0.0, 0.0)
    p50, p95, p99 = np.percentile(v, [50, 95, 99])
    return Latency(round(float(p50), 3), round(float(p95), 3), round(float(p99), 3), round(float(v.max()), 3))


def _throughput(
    result: RunResult, sensor_rate_hz: float, seconds: float, cached: bool, times_known: bool = True
) -> Throughput:
    """Throughput over the pipeline's `seconds` (see LiveFrontEnd.stream) and per-step latency (`times_known`
    False: the frames' times are frame numbers, see frame_rate_hz, which falls back on `sensor_rate_hz`)."""
    mem, n = result.memory, len(result)
    assert mem is not None, "the online protocol records the memory series before its throughput"
    backend = _backend_seconds(result)
    graph_steps = result.steps_ms["graph_update"][mem["keyframes"] > np.concatenate([[0], mem["keyframes"][:-1]])]
    rate, rate_from = frame_rate_hz(float(result.times[0]), float(result.times[-1]), n, sensor_rate_hz, times_known)
    fps, realtime_factor = throughput(n, seconds, rate)
    latency = {
        "backend": _percentiles(result.backend_ms),
        **{s: _percentiles(result.steps_ms[s]) for s in STEPS},
        "graph_update_per_keyframe_step": _percentiles(graph_steps),
    }
    return Throughput(
        round(seconds, 4),
        fps,
        n / backend if backend > 0 else float("inf"),
        rate,
        rate_from,
        realtime_factor,
        latency,
        cached,
    )


def _backend_seconds(result: RunResult) -> float:
    return float(result.backend_ms.sum()) / 1e3 + result.final_s["optimisation"]


def _timing(result: RunResult, replayed_s: dict[str, float]) -> Timing:
    """Seconds per step, the final optimisation's and the back end's in all."""
    totals = {s: float(result.steps_ms[s].sum()) / 1e3 for s in STEPS}
    stages = {
        **{s: round(v, 4) for s, v in totals.items()},
        "final_optimisation": round(result.final_s["optimisation"], 4),
        "backend_total": round(_backend_seconds(result), 4),
    }
    return Timing(stages, replayed_s)


def frame_rate_hz(
    first: float, last: float, frames: int, fallback: float, times_known: bool = True
) -> tuple[float, str]:
    """The data's frame rate and where it comes from: `frames` frames timed `first` to `last` (the frames' own
    timestamps, so a 20 Hz sensor or every other scan, `--jump 2`, counts as recorded), else `fallback` (the
    config's sensor_rate_hz) while they span no time or are not timestamps (`times_known` False: frame
    numbers, which would make the rate 1 frame/s)."""
    if not times_known:
        return fallback, NO_TIMESTAMPS
    span = last - first
    return ((frames - 1) / span, "timestamps") if frames > 1 and span > 0 else (fallback, "sensor_rate_hz")


class LiveView(Protocol):
    """A live view of the run (msa_slam.viz.live.LiveViewer), told about every frame and the result."""

    def frame(self, backend: SlamBackend, index: int, points: np.ndarray, new_keyframes: list[int]) -> None: ...
    def finish(self, result: RunResult) -> None: ...


def open_recording(config: OnlineConfig, quiet: bool = True, window_fix: str = CONFIG_WINDOW_FIX) -> FrameSource:
    """The frames of `config`'s dataset (with its source options), refused before any work when they cannot serve
    the run: gt-noise odometry without ground truth, a sampler window the frames read never fill (check_window;
    `window_fix`: what the error says to change)."""
    recording = open_source(
        config.dataset, config.dataset_kind, config.cache_dir, not quiet, config.source, config.mode
    )
    if recording.gt_poses is None and config.odometry == "gt-noise":
        raise InputError(
            f"dataset {config.dataset!r}: odometry gt-noise perturbs ground truth, which this "
            "recording lacks; use --odometry kiss or a pose file"
        )
    frames = len(recording) if config.max_frames is None else min(len(recording), config.max_frames)
    check_window(config, frames, window_fix)
    return recording


def make_online_odometry(config: OnlineConfig, source: FrameSource, n: int):
    """(odometry object, cached) - gt-noise, a pose file, or KISS-ICP (replayed from the cache when it has the
    frames this run reads, so grids do not redo it: a ReplayedOdometry with the time each frame took computed;
    live otherwise; deskew as in the batch pipeline's key: on when the source's frames carry per-point times, see
    make_odometry). Scans on disk are keyed as in the batch pipeline, by the selection (--first/--jump/-n); a
    live: source's frames by their identity, with KISS-ICP on one thread only (prepare_live_odometry: what
    would not be reproducible is not replayed), its first `n` frames from the entry of all of them."""
    if config.odometry == "gt-noise":
        if source.gt_poses is None:  # open_recording refuses this before any work; a source given directly here
            raise InputError(f"{source.name}: odometry gt-noise perturbs ground truth, which these frames lack")
        try:
            return NoisyOdometry(source.gt_poses[:n], seed=config.seed, **config.odometry_params), False
        except TypeError:
            raise InputError(
                f"odometry gt-noise: bad parameters {sorted(config.odometry_params)}; it takes "
                "translation_noise, rotation_noise_deg"
            ) from None
    odometry = make_odometry(config, len(source), source.point_times)
    key = _odometry_key(config, source, odometry)
    if key is not None:
        cache = OdometryCache(pipeline_cache(config.cache_dir))
        entry = cache.load_entry(key(cache.store), len(source))
        if entry is not None:
            assert isinstance(odometry, KissOdometry), "only KISS-ICP is cached (_odometry_key)"
            odometry.unregistered_frames = [frame for frame in entry[1] if frame < n]
            return ReplayedOdometry(entry[0], entry[2], odometry.unregistered_warning(n)), True
    return odometry, False


def _odometry_key(config: OnlineConfig, source: FrameSource, odometry: object) -> Callable[[CacheDir], str] | None:
    """How the cached odometry of `source` is keyed (given the cache folder, which memoises the scans' digests),
    or None when it is not cached: only KISS-ICP is, on scans on disk or on a live: source with an identity
    registered on one thread."""
    if not isinstance(odometry, KissOdometry):
        return None
    if source.sequence is not None:
        sequence = source.sequence
        return lambda store: OdometryCache.key(sequence, odometry.config, store=store)
    if source.identity is not None and odometry_threads(config) == 1:
        identity = source.identity
        return lambda store: OdometryCache.source_key(identity, odometry.config)
    return None


def prepare_live_odometry(config: OnlineConfig, quiet: bool = True) -> bool:
    """Register every frame of `config`'s live: source once and cache the poses, so that the online runs of every
    sampler on it replay them (make_online_odometry) rather than each running KISS-ICP again; their results are
    the same bytes as without the cache (one thread: a fixed order of the ICP's sums). Returns whether the cache
    holds them now; False when this odometry is not cached (another odometry, or KISS-ICP on several threads)."""
    if config.odometry != "kiss":
        return False
    source = open_recording(config)
    if source.live:
        config = with_odometry_threads(config, available_cpus())  # as LiveFrontEnd.start: the same key
    odometry = make_odometry(config, len(source), source.point_times)
    key = _odometry_key(config, source, odometry)
    if key is None or source.sequence is not None:  # scans on disk: the batch front end caches them
        return False
    cache = OdometryCache(pipeline_cache(config.cache_dir))
    name = key(cache.store)
    if cache.load_entry(name, len(source)) is None:
        with closing(arriving(source, len(source))) as frames:
            poses, ms = register_frames(odometry, frames, len(source), source.times_known, quiet, "odometry")
        assert isinstance(odometry, KissOdometry), "only KISS-ICP is cached (_odometry_key)"
        if cache.save(name, poses, odometry.unregistered_frames, ms) is None:
            return False
    return True


def arriving(source: FrameSource, n: int) -> Generator[Frame, None, None]:
    """The first `n` frames of `source`. A live source's are made a few ahead of the odometry, as a sensor's
    driver delivers them: by a spawned process (its `producer`; KISS-ICP's binding holds the GIL while it
    registers a scan, so a thread would simulate little beside it), else by a thread: for fewer than
    PARALLEL_MIN_FRAMES frames (the process's start-up would cost more than it saves) or where this process may
    not have children (a Dask worker). Close it when done: the maker stops."""
    if not source.live:
        yield from islice(source.frames(), n)
        return
    from msa_slam.sim.config import PARALLEL_MIN_FRAMES  # here: the simulator (trimesh) is slow to import

    if source.producer is not None and n >= PARALLEL_MIN_FRAMES and not multiprocessing.current_process().daemon:
        yield from islice(spawned_ahead(source.producer, DEPTH), n)
    else:
        yield from islice(ahead(source.frames()), n)


def with_odometry_threads(config: OnlineConfig, threads: int) -> OnlineConfig:
    """`config` with KISS-ICP on `threads` threads unless its odometry_params name a count (an explicit setting
    wins) or its odometry is not KISS-ICP; written into odometry_params so that config.yaml re-runs what ran."""
    if config.odometry != "kiss" or "num_threads" in config.odometry_params:
        return config
    return config.model_copy(update={"odometry_params": {**config.odometry_params, "num_threads": threads}})


def odometry_threads(config: OnlineConfig) -> int | None:
    """Threads KISS-ICP registers with (its 0, "automatic", counted as the cores it may use); None for another
    odometry."""
    if config.odometry != "kiss":
        return None
    return config.odometry_params.get("num_threads", DEFAULT_THREADS) or available_cpus()


def threads_note(threads: int | None) -> list[str]:
    """The run's warning when its odometry is multi-threaded (none otherwise): for its notes and the log."""
    if threads is None or threads <= 1:
        return []
    return [
        f"odometry: KISS-ICP on {threads} threads, {NOT_REPRODUCIBLE}: -p odometry.num_threads=1 makes the "
        "run deterministic"
    ]


class ProgressFigures(TypedDict, total=False):
    """The fields of online_progress's line (none when quiet)."""

    fps: float
    rtf: float
    kf: int
    loops: int


def online_progress(quiet: bool) -> Progress | LogProgress:
    """Progress with frames per second and real-time factor (a bar on a terminal, log lines elsewhere)."""
    return progress_bar(
        quiet,
        transient=False,
        fields="{task.fields[fps]:6.1f} fps  RTF {task.fields[rtf]:5.2f}x  "
        "kf {task.fields[kf]}  loops {task.fields[loops]}",
    )


class LiveFrontEnd:
    """The frames of `source` one by one, odometry and descriptor computed as each arrives (pipeline.driver.run);
    `viewer` (msa_slam.viz.live.LiveViewer) is shown every frame and the final result. One run's: start() sets it
    up for that run."""

    def __init__(self, source: FrameSource, viewer: LiveView | None = None) -> None:
        self.source, self.viewer = source, viewer
        self.frames = len(source)

    @property
    def name(self) -> str:
        return self.source.name

    def __len__(self) -> int:
        return self.frames

    @property
    def descriptor_shape(self) -> tuple[int, ...]:
        return self.descriptor.shape

    def clouds_for(self, config: RunConfig) -> None:
        """None: each keyframe's cloud is downsampled as its frame arrives."""
        return None

    def start(self, config: RunConfig) -> OnlineConfig:
        """The run's odometry (KISS-ICP on every core for a live source, replayed from the cache when it has the
        scans), descriptor and notes; `config` as it runs (an OnlineConfig: a batch RunConfig is refused)."""
        if not isinstance(config, OnlineConfig):
            raise InputError(f"run: the live front end runs an OnlineConfig, not a {type(config).__name__}")
        source = self.source
        if source.live:  # frames that come once: no replay to keep bit for bit, so every core
            config = with_odometry_threads(config, available_cpus())
        self.threads = odometry_threads(config)
        self.frames = len(source) if config.max_frames is None else min(len(source), config.max_frames)
        self.odometry, self.cached = make_online_odometry(config, source, self.frames)
        self.notes = source_warnings(config, source.name, source.times_known, source.point_times)  # logged already
        for note in threads_note(self.threads):
            logger.warning(note)
            self.notes.append(note)
        self.deskew = deskew_record(config, source.point_times)
        config = config_as_run(config, source.point_times)  # what result.config (config.yaml) records
        self.descriptor = make_descriptor(config.descriptor, **config.descriptor_params)
        self.config = config
        return config

    def close(self) -> None:
        """Nothing runs beside a live front end between its frames (its reader stops with its stream)."""

    def stream(self, backend: SlamBackend, quiet: bool) -> RunResult:
        """Each frame: odometry, descriptor, the back end (and the viewer), with a progress line of frames per
        second and real-time factor; then finish(). The pipeline's seconds (replayed odometry counted with the time
        it took computed) and the front end's per-frame times are kept for record()."""
        config, source, odometry, descriptor = self.config, self.source, self.odometry, self.descriptor
        n = self.frames
        self.front_ms = front_ms = {s: np.zeros(n, dtype=np.float32) for s in STEPS[:2]}
        times_known = source.times_known
        if not times_known and source.sequence is None:  # a sequence opened from files has said so (UNTIMED)
            logger.warning(
                "online: the frames have no timestamps; the real-time factor is taken against the "
                "config's sensor_rate_hz (%g Hz)",
                config.sensor_rate_hz,
            )
        replayed = isinstance(odometry, ReplayedOdometry)
        label = f"online {config.name}" + (
            " (odometry replayed from the cache, counted as computed)"
            if replayed
            else f" (odometry: {noun_count(self.threads, 'thread')})"
            if self.threads is not None
            else ""
        )
        with online_progress(quiet) as bar, closing(backend), closing(arriving(source, n)) as frames:
            task = bar.add_task(label, total=n, fps=0.0, rtf=0.0, kf=0, loops=0)
            start, first_time = time.perf_counter(), None
            credit = 0.0  # s: replayed odometry's time as computed, less the time its replay took
            counted = accepted = 0  # backend.loops only grows: the loops counted so far, and how many were accepted

            def figures(frames: int, last_time: float, keyframes: int, seconds: float) -> ProgressFigures:
                """The progress line's fields after `frames` frames in the pipeline's `seconds`."""
                nonlocal counted, accepted
                if quiet:
                    return {}
                accepted += sum(c.accepted for c in backend.loops[counted:])
                counted = len(backend.loops)
                first = last_time if first_time is None else first_time
                rate = frame_rate_hz(first, last_time, frames, config.sensor_rate_hz, times_known)[0]
                fps, rtf = throughput(frames, seconds, rate)
                return {"fps": fps, "rtf": rtf, "kf": keyframes, "loops": accepted}

            for i, frame in enumerate(frames):
                first_time = frame.time if first_time is None else first_time
                t0 = time.perf_counter()
                pose = odometry.register(
                    frame.points,
                    frame.timestamps,  # times: for deskew
                    frame.time if times_known else None,
                )
                t1 = time.perf_counter()
                if replayed:
                    credit += odometry.ms[i] / 1e3 - (t1 - t0)
                desc = np.asarray(descriptor.compute(frame.points, frame=i), dtype=np.float64)
                front_ms["odometry"][i] = odometry.ms[i] if replayed else (t1 - t0) * 1e3
                front_ms["descriptor"][i] = (time.perf_counter() - t1) * 1e3
                new = backend.add_frame(pose, desc, frame.points, frame.gt_pose, frame.time)
                if self.viewer is not None:
                    self.viewer.frame(backend, i, frame.points, new)
                if i < n - 1:  # every frame, so a failure reports the frame it stopped at; the last: after finish()
                    bar.update(
                        task,
                        completed=i + 1,
                        **figures(i + 1, frame.time, len(backend.store), time.perf_counter() - start + credit),
                    )
            result = backend.finish()  # flushes the sampler: the last line counts the keyframes the report does
            self.seconds = time.perf_counter() - start + credit  # the pipeline's, as metrics.json and report.md give it
            bar.update(
                task,
                completed=len(result),
                **figures(len(result), float(result.times[-1]), len(result.keyframes), self.seconds),
            )
        assert isinstance(backend.recorder, MemoryRecorder), "an online run's back end records memory (driver._backend)"
        self.recorder = backend.recorder
        if self.viewer is not None:
            self.viewer.finish(result)
        return result

    def record(
        self, result: RunResult, clouds: object, sweep: object, sweep_off: str
    ) -> tuple[RunResult, ProtocolRecord]:
        """`result` with the front end's per-frame times and the memory series, and the online protocol's record:
        notes and the odometry's warnings, timing, threads and throughput (no threshold sweep: a batch analysis)."""
        config, odometry, m = self.config, self.odometry, len(result)
        steps_ms = {**{s: v[:m] for s, v in self.front_ms.items()}, **result.steps_ms}
        memory = {k: v[:m] for k, v in self.recorder.memory.items()}
        front = [steps_ms[s] for s in self.front_ms]
        records = result.memory_bytes["record_bytes"] + sum(v.nbytes for v in (*memory.values(), *front))  # per-frame
        result = replace(
            result, steps_ms=steps_ms, memory=memory, memory_bytes={**result.memory_bytes, "record_bytes": records}
        )
        warnings = frontend_warnings(result.gt_poses, result.odometry, result.times)
        if isinstance(odometry, KissOdometry):
            warnings += odometry.unregistered_warning(m)
        elif isinstance(odometry, ReplayedOdometry):
            warnings += odometry.notes
        for warning in warnings:
            logger.warning(warning)
        replayed = isinstance(odometry, ReplayedOdometry)
        replayed_s = {"odometry": round(float(odometry.ms[:m].sum()) / 1e3, 4)} if replayed else {}
        threads_used = {"odometry": self.threads, "verification": config.verifier.num_threads, "blas_backend": 1}
        return result, ProtocolRecord(
            ONLINE,
            (*self.notes, *warnings),
            _timing(result, replayed_s),
            RunSetup(self.deskew, threads_used),
            throughput=_throughput(result, config.sensor_rate_hz, self.seconds, self.cached, self.source.times_known),
            cloud_store=config.cloud_store,
        )
