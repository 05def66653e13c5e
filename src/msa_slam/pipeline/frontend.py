"""The cached batch front end (the paper's Table I protocol): odometry, descriptors and downsampled clouds of every
frame, computed once and cached on disk, streamed through the back end (pipeline.driver.run), which Levenberg-
Marquardt optimises once at the end; the run then records ATE/RPE before and after, PR-AUC/F1-max of both
place-recognition protocols, time and, when asked, the threshold sweep.

These are the expensive stages that do not depend on the sampler, so `compare` runs them once and every
sampler reuses them; a re-run finds them in the cache (keyed by the scans' content, settings, the code that
computes them and library versions: see msa_slam.io.cache).
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any, TypeVar

import numpy as np

from msa_slam.datasets import ScanSequence
from msa_slam.datasets.sequences import UNTIMED
from msa_slam.descriptors import Descriptor, make_descriptor
from msa_slam.descriptors.cache import descriptor_key
from msa_slam.errors import InputError
from msa_slam.evaluation import StageTimer
from msa_slam.evaluation.metrics import (
    BATCH,
    Deskew,
    ProtocolRecord,
    ReferencePR,
    RunSetup,
    SweepRow,
    Timing,
    Unavailable,
    sampler_realtime_fraction,
)
from msa_slam.evaluation.metrics_reader import NO_REASON
from msa_slam.evaluation.resources import peak_rss_bytes
from msa_slam.evaluation.sanity import frontend_warnings
from msa_slam.io.cache import CacheDir, Computed, pipeline_cache
from msa_slam.odometry import KissOdometry, PosesFromFile
from msa_slam.odometry.cache import OdometryCache
from msa_slam.odometry.choice import deskew_choice, deskew_dropped, make_odometry
from msa_slam.odometry.kiss import NO_POINT_TIMES
from msa_slam.pipeline.config import RunConfig
from msa_slam.pipeline.read_ahead import FrameHook, FrontEndStages, frontend_pass
from msa_slam.place_recognition import PRCurve, precision_recall
from msa_slam.place_recognition.metrics import reference_protocol_matches
from msa_slam.progress import progress_bar
from msa_slam.registration.cloud_cache import ComputedClouds, FrameClouds, cloud_key
from msa_slam.sampling.msa.sampler import warn_short_stream
from msa_slam.sampling.msa.warm import compile_in_background
from msa_slam.slam import BACKEND_STEPS, RunResult, SlamBackend
from msa_slam.slam.backend import MIN_KEYFRAMES
from msa_slam.slam.loop_closing import protocol
from msa_slam.slam.result import RunSettings
from msa_slam.sources import open_sequence

logger = logging.getLogger(__name__)

# A cold KISS-ICP front end of this many frames keeps one core busy longer than MSA's kernels take to compile
# (about a minute of CPU on this project's 2-core machine, at 0.1-0.3 s a frame of KISS-ICP)
COMPILE_ALONGSIDE_FRAMES = 300
Config = TypeVar("Config", bound=RunConfig)  # a batch or online (OnlineConfig) run's config

# What to change when a sampler's window is longer than the frames read (check_window: `frames`, `window`), in
# the config's terms; the commands name their options instead (cli.options.WINDOW_FIX)
CONFIG_WINDOW_FIX = "use a window of at most {frames} frames (sampler_params window={frames}) or flush=true"
BACKEND_STAGES = (*BACKEND_STEPS, "optimisation")


@dataclass
class CachedFrontEnd:
    """A sequence with its ground truth (None when the recording has none), odometry, per-frame descriptors and
    downsampled clouds (None for the local-map loop detectors, whose keyframe clouds are local maps), plus how
    long they took."""

    sequence: ScanSequence
    gt_poses: np.ndarray | None
    odometry: np.ndarray
    descriptors: np.ndarray
    descriptor: Descriptor
    odometry_config: dict[str, Any]
    timer: StageTimer = field(default_factory=StageTimer)
    cached: dict[str, bool] = field(default_factory=dict)
    descriptor_settings: tuple = (None, None)
    odometry_effective: dict[str, Any] = field(default_factory=dict)  # the odometry's full effective config
    warnings: list[str] = field(default_factory=list)  # source_warnings, degenerate odometry or ground truth
    replayed_s: dict[str, float] = field(default_factory=dict)  # stages read from the cache: s they took computed
    deskew: Deskew = Deskew(None, "not recorded")  # the deskew done (deskew_record)
    clouds: FrameClouds | None = None

    def clouds_for(self, config: RunConfig) -> FrameClouds | None:
        """The frame clouds when `config` stores scans downsampled as they were (its loop detector and voxel size),
        else None: its back end downsamples what it stores itself."""
        clouds = self.clouds
        return clouds if clouds is not None and stores_clouds_as_given(config, clouds.voxel_size) else None

    def __len__(self) -> int:
        return len(self.sequence)

    @property
    def name(self) -> str:
        return self.sequence.name

    def matches(self, config: RunConfig) -> bool:
        """True when `config` asks for this front end (same odometry and descriptor settings)."""
        return self.odometry_config == _odometry_config(config, len(self)) and self.descriptor_settings == (
            config.descriptor,
            config.descriptor_params,
        )

    @property
    def descriptor_shape(self) -> tuple[int, ...]:
        return self.descriptors.shape[1:]

    def start(self, config: Config) -> Config:
        """`config` as it runs on this front end (config_as_run: what config.yaml records); one that asks for other
        odometry or descriptor settings is refused."""
        if not self.matches(config):
            raise InputError("run: the given front end was built with other odometry/descriptor settings")
        return config_as_run(config, self.sequence.point_times)

    def stream(self, backend: SlamBackend, quiet: bool) -> RunResult:
        """Every frame's cached odometry and descriptor (its scan read only when the back end stores it) through
        `backend`, then its finish()."""
        sequence, times, gt = self.sequence, self.sequence.times, self.gt_poses
        with progress_bar(quiet) as bar:
            task = bar.add_task(f"back-end ({backend.settings.name})", total=len(self))
            for i in range(len(self)):
                backend.add_frame(
                    self.odometry[i],
                    self.descriptors[i],
                    partial(frame_points, sequence, i),
                    None if gt is None else gt[i],
                    times[i],
                )
                bar.advance(task)
        return backend.finish()

    def close(self) -> None:
        """Nothing runs beside a computed front end."""

    def record(
        self, result: RunResult, clouds: Any, sweep: Sweep | None, sweep_off: str
    ) -> tuple[RunResult, ProtocolRecord]:
        """`result` with the reference protocol's precision-recall, and the batch protocol's record: timing (the
        sampler's share of real time too), the reference protocol's PR-AUC / F1-max and the threshold sweep
        (`sweep`, on the run's `clouds`; else why not: `sweep_off`)."""
        gt = self.gt_poses
        sims, dists = (
            reference_protocol_matches(self.descriptor, result.keyframes, self.descriptors, gt)
            if gt is not None
            else (np.zeros(0), np.zeros(0))
        )
        result = replace(
            result,
            descriptors=self.descriptors[: len(result)],
            pr_reference=precision_recall(sims, dists, result.config.loop_radius) if len(sims) else None,
        )
        reasons: dict[str, str | None] = {}
        fraction = sampler_realtime_fraction(result.sampler_stats, result.times, self.sequence.times_known)
        if isinstance(fraction, Unavailable):
            reasons["sampler_realtime_fraction"] = fraction.reason
        reasons["pr_reference"] = _reference_reason(result.pr_reference, gt is not None)
        peak = peak_rss_bytes()  # the run's, without the sweep's replays
        rows, seconds = _sweep(result, self, clouds, sweep, sweep_off, reasons)
        reference = _reference(result.pr_reference, reasons["pr_reference"], len(sims))
        return result, ProtocolRecord(
            BATCH,
            tuple(self.warnings),
            _timing(result, self, fraction, seconds),
            RunSetup(self.deskew, _threads(result.config, self), self.odometry_effective),
            {k: v for k, v in reasons.items() if v is not None},
            reference,
            rows,
            peak_rss_bytes=peak,
        )


# The threshold sweep a batch run may add (experiments.sweep.threshold_sweep): (run, its front end, its clouds) -> rows
Sweep = Callable[[RunResult, CachedFrontEnd, Any], tuple[SweepRow, ...]]


def stores_clouds_as_given(config: RunConfig, voxel_size: float) -> bool:
    """Whether a run of `config` keeps the frames' clouds downsampled at `voxel_size` as they are: its loop detector
    stores single scans (not local maps) and its verifier uses that voxel size."""
    return config.loop_detector == "scan" and voxel_size == config.verifier.voxel_size


def frame_points(sequence: ScanSequence, i: int) -> np.ndarray:
    """Frame `i`'s scan, read when the back end stores it."""
    return sequence[i].points


def _odometry_config(config: RunConfig, n_frames: int) -> dict[str, Any]:
    return {
        "odometry": config.odometry,
        "params": config.odometry_params,
        "frames": n_frames,
        "source": config.source.model_dump(),
    }


def deskew_record(config: RunConfig, point_times: bool | None) -> Deskew:
    """The deskew done (metrics.json `deskew`: true, false, or null for an odometry other than KISS-ICP) and why."""
    return Deskew(*deskew_choice(config, point_times))


def config_as_run(config: Config, point_times: bool | None) -> Config:
    """`config` as its odometry runs: deskew false when make_odometry switches it off (deskew_dropped), so that
    config.yaml agrees with metrics.json and re-runs what ran."""
    if not deskew_dropped(config, point_times):
        return config
    return config.model_copy(update={"odometry_params": {**config.odometry_params, "deskew": False}})


def source_warnings(config: RunConfig, name: str, times_known: bool, point_times: bool | None) -> list[str]:
    """The run's warnings about its scans (`name`) for report.md, each logged once where it is decided: no
    timestamps (frame k at k s, datasets.sequences), deskew switched off without per-point times (make_odometry)."""
    return ([f"{name}: {UNTIMED}"] if not times_known else []) + (
        [NO_POINT_TIMES] if deskew_dropped(config, point_times) else []
    )


def check_window(config: RunConfig, n_frames: int, fix: str = CONFIG_WINDOW_FIX) -> None:
    """Before the front end: a sampler window longer than the `n_frames` read never fills, so the run could end,
    after odometry and descriptors, with too few keyframes for the evaluation. Without the end-of-stream flush
    only frame 0 is ever a keyframe: an error with `fix` (formatted with `frames` and `window`); with it, the
    sampler's own warning now rather than after the front end (a warning, as the flush may still pick enough)."""
    window = getattr(config.sampler_params, "window", None)
    if window is None or n_frames >= window:
        return
    if not config.flush:
        raise InputError(
            f"sampler {config.name!r}: window={window} is longer than the {n_frames} frames read, so it "
            f"never fills and only frame 0 becomes a keyframe (flush is off); the evaluation needs at "
            f"least {MIN_KEYFRAMES}: " + fix.format(frames=n_frames, window=window)
        )
    warn_short_stream(n_frames, window, flush=True)


def replayed_seconds(stages: Mapping[str, Computed | ComputedClouds], timer: StageTimer) -> dict[str, float]:
    """Stage -> seconds computing it took, for the `stages` replayed from the cache; `timer` counts them too (a
    replayed stage costs what it took when computed: speed figures are those of the whole pipeline)."""
    replayed = {name: float(stage.ms.sum()) / 1e3 for name, stage in stages.items() if stage.cached}
    for name, seconds in replayed.items():
        timer.seconds[name] = timer.seconds.get(name, 0.0) + seconds
    return replayed


def prepare_frontend(
    config: RunConfig, quiet: bool = True, samplers: Sequence[RunConfig] = (), window_fix: str = CONFIG_WINDOW_FIX
) -> CachedFrontEnd:
    """Open the dataset (once: for a large bag that is a full indexing), check that the sampler windows of
    `samplers` (default: `config`'s; compare: every method's) fit the frames read (check_window, with
    `window_fix`), then odometry, descriptors and (scan loop detector) clouds downsampled at the verifier's voxel
    size for all frames (cached per sequence; those missing from the cache computed in one pass over the scans:
    read_ahead.frontend_pass)."""
    return compute_frontend(plan_frontend(config, quiet, samplers, window_fix), samplers)


def compute_frontend(plan: FrontEndPlan, samplers: Sequence[RunConfig] = ()) -> CachedFrontEnd:
    """The stages of `plan` computed (or replayed from the cache), MSA's kernels compiled alongside when a method
    of `samplers` (default: the plan's config) needs them."""
    _compile_msa_alongside(samplers or (plan.config,), plan)
    return plan.assemble(plan.run_pass())


@dataclass
class FrontEndPlan:
    """A cached front end opened and checked, its stages not computed yet: what frontend_pass needs, and how its
    stages become a CachedFrontEnd (`assemble`)."""

    config: RunConfig
    sequence: ScanSequence
    cache: CacheDir
    odometry: KissOdometry | PosesFromFile
    descriptor: Descriptor
    key: str  # the descriptors' cache key
    clouds: tuple[float, str] | None  # (voxel size, cache key) of the frame clouds; None for local-map detectors
    timer: StageTimer
    quiet: bool

    @property
    def pose_file(self) -> list[str]:
        return [self.odometry.path] if isinstance(self.odometry, PosesFromFile) else []

    @property
    def odometry_cached(self) -> bool:
        """Whether the odometry's poses are in the cache (the pass then only reads what else is missing)."""
        key = OdometryCache.key(self.sequence, self.odometry.config, self.pose_file, self.cache)
        return OdometryCache(self.cache).path(key).is_file()

    def run_pass(self, on_frame: FrameHook | None = None) -> FrontEndStages:
        """The front end's stages (read_ahead.frontend_pass), each frame to `on_frame` as the pass completes it."""
        return frontend_pass(
            self.sequence,
            self.odometry,
            self.descriptor,
            self.cache,
            self.key,
            self.config.descriptor != "precomputed",  # one pass
            self.pose_file,
            self.quiet,
            self.timer,
            self.clouds,
            on_frame,
        )

    def assemble(self, stages: FrontEndStages) -> CachedFrontEnd:
        """The CachedFrontEnd of these stages, with the warnings about its scans and odometry (logged here)."""
        config, sequence, timer = self.config, self.sequence, self.timer
        n = len(sequence)
        poses, descriptors = stages.odometry, stages.descriptors
        replayed = replayed_seconds(stages.by_name(), timer)
        if replayed and not self.quiet:  # where a computed stage shows its progress
            print(
                "front end replayed from the cache: "
                + ", ".join(f"{name} (computed in {seconds:.1f} s)" for name, seconds in replayed.items()),
                file=sys.stderr,
            )
        sanity = frontend_warnings(sequence.gt_poses, poses.values, sequence.times)
        if isinstance(self.odometry, KissOdometry):
            sanity += self.odometry.unregistered_warning(n)
        for warning in sanity:
            logger.warning(warning)
        warnings = [*source_warnings(config, sequence.name, sequence.times_known, sequence.point_times), *sanity]
        frontend = CachedFrontEnd(
            sequence,
            sequence.gt_poses,
            poses.values,
            descriptors.values,
            self.descriptor,
            _odometry_config(config, n),
            timer,
            {k: v.cached for k, v in stages.by_name().items()},
            odometry_effective=dict(self.odometry.config),
            warnings=warnings,
            replayed_s=replayed,
            deskew=deskew_record(config, sequence.point_times),
            clouds=None if stages.clouds is None else stages.clouds.values,
        )
        frontend.descriptor_settings = (config.descriptor, config.descriptor_params)
        return frontend


def plan_frontend(
    config: RunConfig, quiet: bool = True, samplers: Sequence[RunConfig] = (), window_fix: str = CONFIG_WINDOW_FIX
) -> FrontEndPlan:
    """The dataset opened and every check made that can refuse the run before its long work (prepare_frontend)."""
    timer = StageTimer()
    with timer.stage("dataset"):
        sequence = open_sequence(
            config.dataset,
            config.dataset_kind,
            config.cache_dir,
            not quiet,
            config.source,
            config.mode,
            keep_parsed=True,
        )
    n = len(sequence)
    for checked in samplers or (config,):
        check_window(checked, n, window_fix)
    if sequence.gt_poses is None and config.sample_on == "gt":
        raise InputError(
            f"dataset {config.dataset!r}: sample_on=gt needs ground-truth poses; this recording has "
            "none (use sample_on=odometry, or give them with --gt FILE)"
        )
    cache = CacheDir(pipeline_cache(config.cache_dir))
    odometry = make_odometry(config, n, sequence.point_times)
    params = dict(config.descriptor_params)
    if config.descriptor == "precomputed":
        params.setdefault("n_frames", n)
    descriptor = make_descriptor(config.descriptor, **params)
    with timer.stage("descriptors"):
        key = descriptor_key(sequence, config.descriptor, config.descriptor_params, cache)
    clouds = None
    if config.loop_detector == "scan":  # the local-map detectors store local maps, built from the scans
        with timer.stage("clouds"):
            voxel = config.verifier.voxel_size
            clouds = (voxel, cloud_key(sequence, voxel, cache))
    return FrontEndPlan(config, sequence, cache, odometry, descriptor, key, clouds, timer, quiet)


def _compile_msa_alongside(samplers: Sequence[RunConfig], plan: FrontEndPlan) -> None:
    """Where this front end is about to run KISS-ICP on one core for minutes and a method samples with MSA, start
    compiling MSA's kernels on the other core (sampling.msa.warm.compile_in_background, lowest priority), so the
    first window loads them from numba's cache instead of compiling them after the front end, on the run's
    critical path (about a minute of CPU after a fresh install; an installed cache only loads them, seconds).
    Skipped for short sequences and when the odometry is cached (the front end is then short)."""
    msa = next((s for s in samplers if s.sampler == "msa"), None)
    if msa is None or not isinstance(plan.odometry, KissOdometry) or len(plan.sequence) < COMPILE_ALONGSIDE_FRAMES:
        return
    if plan.odometry_cached:
        return
    compile_in_background(dict(msa.sampler_params), plan.descriptor.shape)


def _sweep(
    result: RunResult,
    frontend: CachedFrontEnd,
    clouds: Any,
    sweep: Sweep | None,
    sweep_off: str,
    reasons: dict[str, str | None],
) -> tuple[tuple[SweepRow, ...] | Unavailable, float | None]:
    """The threshold sweep's rows and seconds (`sweep`: msa_slam.experiments.sweep.threshold_sweep), or why it did
    not run (also put into `reasons`)."""
    if sweep is None:
        why = sweep_off
    elif protocol(result.config) != "paper":
        why = "the verified loop protocol does not use similarity_threshold (its floor: verified_min_similarity)"
    elif result.gt_poses is None:
        why = "no ground truth: ATE improvement is undefined"
    else:
        start = time.perf_counter()
        rows = sweep(result, frontend, clouds)
        return rows, round(time.perf_counter() - start, 4)  # not in backend_total
    reasons["threshold_sweep"] = why
    return Unavailable(why), None


def _reference(pr: PRCurve | None, reason: str | None, matches: int) -> ReferencePR:
    """PR-AUC / F1-max of the reference example's protocol, each unavailable with `reason` when undefined."""
    auc, f1 = (None, None) if pr is None else (pr.auc, pr.f1_max)
    gone = Unavailable(reason or NO_REASON)
    return ReferencePR(gone if auc is None else auc, gone if f1 is None else f1, matches)


def _reference_reason(pr: PRCurve | None, ground_truth: bool) -> str | None:
    """Why the reference protocol's PR-AUC / F1-max are unavailable (None when they are not)."""
    if not ground_truth:
        return "no ground truth: true loops cannot be told from false ones"
    if pr is None:
        return (
            "no frame had more than 10 keyframes before it and a best match more than 10 frames away (the "
            "reference protocol recorded no match)"
        )
    return pr.unavailable or None


def _timing(
    result: RunResult, frontend: CachedFrontEnd, fraction: float | Unavailable, sweep_s: float | None
) -> Timing:
    """Seconds per back-end stage (the sweep's last, not in backend_total), the front end's, and the sampler's share
    of real time."""
    times = {s: float(result.steps_ms[s].sum()) / 1e3 for s in BACKEND_STEPS}
    times.update(result.final_s)
    backend_time = sum(times.get(s, 0.0) for s in BACKEND_STAGES)
    stages = {
        **{k: round(v, 4) for k, v in times.items()},
        "backend_total": round(backend_time, 4),
        "threshold_sweep": sweep_s,
    }
    return Timing(
        stages,
        {k: round(v, 4) for k, v in frontend.replayed_s.items()},
        {k: round(v, 4) for k, v in frontend.timer.seconds.items()},
        dict(frontend.cached),
        fraction,
    )


def _threads(config: RunSettings, frontend: CachedFrontEnd) -> dict[str, int | None]:
    return {
        "odometry": frontend.odometry_effective.get("registration", {}).get("max_num_threads"),
        "verification": config.verifier.num_threads,
        "blas_backend": 1,
    }
