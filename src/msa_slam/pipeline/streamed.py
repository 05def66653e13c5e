"""A batch run's back end beside its front end: when the odometry has to be computed, the cached front end's pass
(odometry, descriptors, downsampled clouds: read_ahead.frontend_pass) runs in a forked process and hands each frame
on as soon as its pose is computed, and this process feeds it to the back end at once (sampling, keyframes, loop
search and verification on the other core) instead of after the whole pass. On two cores the back end's time then
hides behind KISS-ICP's, which bounds the run (docs/performance.md).

The back end gets the same values in the same order as from the finished front end (CachedFrontEnd.stream), so
the run writes the same bytes; the pass writes the same cache entries, so a re-run replays them. Used by `run`
(pipeline.driver) where it can be: the odometry is not cached, this process may have children, and a forked
process can read the sequence (ScanSequence.forkable); else the front end is computed first (compute_frontend).
`compare` shares one front end between its methods and computes it first.
"""

from __future__ import annotations

import multiprocessing
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import ProtocolRecord
from msa_slam.io.cache import Computed
from msa_slam.odometry import KissOdometry
from msa_slam.pipeline.config import RunConfig
from msa_slam.pipeline.forked_ahead import ForkedProducer
from msa_slam.pipeline.frontend import (
    CONFIG_WINDOW_FIX,
    CachedFrontEnd,
    Config,
    FrontEndPlan,
    Sweep,
    compute_frontend,
    config_as_run,
    frame_points,
    plan_frontend,
    stores_clouds_as_given,
)
from msa_slam.pipeline.read_ahead import FrontEndStages
from msa_slam.registration.cloud_cache import ComputedClouds, load_frame_clouds
from msa_slam.slam import RunResult, SlamBackend

# Frames the pass may run ahead of the back end: a back end's burst of verification (seconds) must not hold the
# odometry up. A frame is its pose, descriptor and downsampled cloud (~0.3 MB at 0.5 m voxels).
STREAM_DEPTH = 64
STREAM_SLOT_BYTES = 4 << 20  # a frame's arrays in one shared memory slot (a larger one goes through the pipe)


def open_frontend(
    config: RunConfig, quiet: bool = True, window_fix: str = CONFIG_WINDOW_FIX
) -> CachedFrontEnd | StreamedFrontEnd:
    """The front end of a batch run of `config`: a StreamedFrontEnd where the back end can run beside the odometry,
    else the front end computed first. Every check that can refuse the run is made here, before the long work."""
    plan = plan_frontend(config, quiet, (), window_fix)
    if streamable(plan):
        return StreamedFrontEnd(plan)
    return compute_frontend(plan)


def streamable(plan: FrontEndPlan) -> bool:
    """Whether `plan`'s pass is worth running beside its back end (KISS-ICP to compute) and can be (a forked
    process reads the scans, and this one may have children: not a Dask or pool worker)."""
    return (
        isinstance(plan.odometry, KissOdometry)
        and getattr(plan.sequence, "forkable", False)
        and not multiprocessing.current_process().daemon
        and not plan.odometry_cached
    )


@dataclass(frozen=True)
class PassSummary:
    """What the forked pass returns besides the frames it handed on: each stage's (cached, ms per frame), its
    stage timer's seconds and the frames the odometry could not register."""

    stages: dict[str, tuple[bool, np.ndarray]]
    seconds: dict[str, float]
    unregistered_frames: list[int]


class StreamedFrontEnd:
    """The front end of pipeline.driver.run whose stages are computed while its back end runs: `start` forks the
    pass, `stream` feeds the back end each frame as it arrives, then holds the finished CachedFrontEnd (`finished`),
    which `record` uses."""

    def __init__(self, plan: FrontEndPlan) -> None:
        self.plan = plan
        self.descriptor = plan.descriptor
        self._pass: ForkedProducer[tuple[int, np.ndarray, np.ndarray, np.ndarray | None], PassSummary] | None = None
        self._clouds = None if plan.clouds is None else ReceivedClouds(plan.clouds[0])
        self._poses = self._descriptors = np.zeros(0)
        self.finished: CachedFrontEnd | None = None

    @property
    def name(self) -> str:
        return self.plan.sequence.name

    def __len__(self) -> int:
        return len(self.plan.sequence)

    @property
    def descriptor_shape(self) -> tuple[int, ...]:
        return tuple(self.plan.descriptor.shape)

    def start(self, config: Config) -> Config:
        """`config` as it runs (config_as_run), the pass started; refuses a config other than the plan's. The
        frames' poses and descriptors get their memory now, written (so resident) before the back end reads its
        starting RSS, as a computed front end's arrays are."""
        if config != self.plan.config:
            raise InputError("run: a streamed front end runs only the configuration it was opened for")
        started = config_as_run(config, self.plan.sequence.point_times)
        if self._pass is None:
            n = len(self)
            self._poses = np.full((n, 4, 4), np.nan)
            self._descriptors = np.full((n, *self.descriptor_shape), np.nan)  # descriptors are float64 (describe)
            self._pass = ForkedProducer(partial(_run_pass, self.plan), STREAM_DEPTH, STREAM_SLOT_BYTES)
            self._pass.start()
        return started

    def clouds_for(self, config: RunConfig) -> ReceivedClouds | None:
        """The frames' clouds as they arrive, when `config` stores them as they are downsampled (as
        CachedFrontEnd.clouds_for)."""
        clouds = self._clouds
        return clouds if clouds is not None and stores_clouds_as_given(config, clouds.voxel_size) else None

    def stream(self, backend: SlamBackend, quiet: bool) -> RunResult:
        """Each frame through `backend` as the pass hands it on (the pass shows the progress), then its finish().
        A frame's cloud is kept only while the back end may still make it a keyframe."""
        if self._pass is None:
            raise RuntimeError("StreamedFrontEnd.stream before start")
        sequence, gt, clouds = self.plan.sequence, self.plan.sequence.gt_poses, self._clouds
        for i, pose, descriptor, cloud in self._pass:
            self._poses[i], self._descriptors[i] = pose, descriptor
            if clouds is not None and cloud is not None:
                clouds.add(i, cloud)
            points = partial(frame_points, sequence, i)
            backend.add_frame(
                self._poses[i], self._descriptors[i], points, None if gt is None else gt[i], sequence.times[i]
            )
            if clouds is not None:
                clouds.forget_before(backend.oldest_selectable)
        summary = self._pass.result
        assert summary is not None, "the pass returns its summary after its last frame"
        result = backend.finish()
        self.finished = self.plan.assemble(self._stages(summary))
        return result

    def _stages(self, summary: PassSummary) -> FrontEndStages:
        """The pass's stages: poses and descriptors as received, the clouds from the cache the pass wrote (mapped,
        as a replayed front end's; None if it could not write them), the odometry's unregistered frames restored
        (for the run's warnings) and the pass's stage times."""
        if isinstance(self.plan.odometry, KissOdometry):
            self.plan.odometry.unregistered_frames = list(summary.unregistered_frames)
        self.plan.timer.seconds = dict(summary.seconds)
        clouds = None
        if self.plan.clouds is not None:
            voxel, key = self.plan.clouds
            stored = load_frame_clouds(self.plan.sequence, voxel, self.plan.cache, key)
            clouds = None if stored is None else ComputedClouds(stored.values, *summary.stages["clouds"])
        return FrontEndStages(
            Computed(self._poses, *summary.stages["odometry"]),
            Computed(self._descriptors, *summary.stages["descriptors"]),
            clouds,
        )

    def record(
        self, result: RunResult, clouds: Any, sweep: Sweep | None, sweep_off: str
    ) -> tuple[RunResult, ProtocolRecord]:
        """As CachedFrontEnd.record, on the front end the pass completed."""
        if self.finished is None:
            raise RuntimeError("StreamedFrontEnd.record before its stream ended")
        return self.finished.record(result, clouds, sweep, sweep_off)

    def close(self) -> None:
        """Stop the pass if it still runs (the run ended early); safe to call twice."""
        if self._pass is not None:
            self._pass.close()


class ReceivedClouds:
    """CloudsByFrame over the clouds received and not forgotten yet: frame i's cloud as a copy in downsample's
    layout (column-major), as FrameClouds gives it, so that the keyframe store holds the same arrays either way."""

    def __init__(self, voxel_size: float) -> None:
        self.voxel_size = float(voxel_size)
        self._clouds: dict[int, np.ndarray] = {}

    def add(self, frame: int, cloud: np.ndarray) -> None:
        self._clouds[frame] = cloud

    def forget_before(self, frame: int) -> None:
        """Drop the clouds of the frames before `frame` (no longer selectable as keyframes)."""
        for old in [f for f in self._clouds if f < frame]:
            del self._clouds[old]

    def __getitem__(self, frame: int) -> np.ndarray:
        if frame not in self._clouds:
            raise KeyError(f"frame {frame}'s cloud was not received or was forgotten (no longer selectable)")
        return np.array(self._clouds[frame], order="F")


def _run_pass(plan: FrontEndPlan, emit: Any) -> PassSummary:
    """In the forked process: the plan's pass, each frame emitted as (index, pose, descriptor, cloud)."""
    stages = plan.run_pass(lambda i, pose, descriptor, cloud: emit((i, pose, descriptor, cloud)))
    return PassSummary(
        {name: (stage.cached, stage.ms) for name, stage in stages.by_name().items()},
        dict(plan.timer.seconds),
        list(getattr(plan.odometry, "unregistered_frames", [])),
    )
