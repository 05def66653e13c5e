"""One run of one sampler, batch or online: `run(config, source)`.

Both protocols drive the same SLAM core (msa_slam.slam) in the same steps; what differs is where the frames come
from and what the run records around the core, which a front end (FrontEnd) provides:
- the cached batch front end (pipeline.frontend.CachedFrontEnd, the paper's Table I protocol): odometry,
  descriptors and downsampled clouds of every frame computed once and cached, streamed through the back end,
  optimised with Levenberg-Marquardt at the end; while they are computed when that can be
  (pipeline.streamed.StreamedFrontEnd: the back end beside the odometry, the same values in the same order);
- the live front end (pipeline.live.LiveFrontEnd, section V-B): frames one by one, odometry and descriptor as
  each arrives, iSAM2 updated as keyframes are finalised, a per-frame memory record.
The config decides the rest: an OnlineConfig runs iSAM2 with its cloud store and the memory recorder, a RunConfig
Levenberg-Marquardt with the clouds in RAM. The threshold sweep, a study over a finished batch run, is passed in
(`sweep`, e.g. msa_slam.experiments.sweep.threshold_sweep) rather than imported, so pipeline/ stays below
experiments/.

BLAS runs single-threaded: the descriptor searches are many small matrix products, which OpenBLAS threads slow
down ~10x on a busy 2-core machine.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Protocol, TypeVar

from threadpoolctl import threadpool_limits

from msa_slam.backend import IncrementalPoseGraph, PoseGraph
from msa_slam.descriptors import Descriptor
from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import ProtocolRecord
from msa_slam.pipeline.config import OnlineConfig, RunConfig
from msa_slam.pipeline.frontend import CONFIG_WINDOW_FIX, Sweep
from msa_slam.pipeline.live import LiveFrontEnd, MemoryRecorder
from msa_slam.pipeline.streamed import open_frontend
from msa_slam.registration import make_cloud_store
from msa_slam.registration.cloud_cache import CloudsByFrame
from msa_slam.sampling.msa.warm import load_kernels
from msa_slam.slam import (
    RunResult,
    SlamBackend,
    build_backend,
    build_loop_closer,
    measure,
    slam_sampler,
)
from msa_slam.sources import open_source

C = TypeVar("C", bound=RunConfig)
SWEEP_NOT_RUN = "not run: left out with `--no-sweep` (the demo leaves it out to stay short)"
RUN_SWEEP_NOT_RUN = "not run (an analysis, not part of the run: pass `--sweep` to add it)"


class FrontEnd(Protocol):
    """Where a run's frames come from, and what its protocol records around the SLAM core."""

    descriptor: Descriptor

    @property
    def name(self) -> str: ...
    def __len__(self) -> int: ...  # the frames the run reads (known once started)
    @property
    def descriptor_shape(self) -> tuple[int, ...]: ...

    def start(self, config: RunConfig) -> RunConfig:
        """Get ready to feed a run of `config`, refusing what cannot run; `config` as it runs (what config.yaml
        records)."""

    def clouds_for(self, config: RunConfig) -> CloudsByFrame | None:
        """Every frame's cloud downsampled as `config` stores keyframes, when the front end has them."""

    def stream(self, backend: SlamBackend, quiet: bool) -> RunResult:
        """Every frame through `backend`, then its finish()."""

    def record(
        self, result: RunResult, clouds: Any, sweep: Sweep | None, sweep_off: str
    ) -> tuple[RunResult, ProtocolRecord]:
        """`result` completed with what the protocol adds to it, and the protocol's part of the run's report (timing,
        warnings, throughput, the sweep)."""

    def close(self) -> None:
        """Stop what the front end still runs (a run that ended early); safe to call twice."""


def run(
    config: C,
    source: FrontEnd | None = None,
    quiet: bool = True,
    sweep: Sweep | None = None,
    sweep_off: str = SWEEP_NOT_RUN,
    window_fix: str = CONFIG_WINDOW_FIX,
) -> RunResult:
    """Run `config`'s sampler over `source` (default: the config's dataset, through the cached front end for a
    RunConfig, the live one for an OnlineConfig; pass pipeline.live.LiveFrontEnd(source, viewer) for another
    frame source or a live viewer) and measure it.

    `sweep` (batch runs only) replays the back end at other similarity thresholds; without it the report gives
    `sweep_off` as the reason. A cached front end built here first refuses a sampler window the frames read never
    fill (streamed.open_frontend; `window_fix`: what the error says to change)."""
    online = isinstance(config, OnlineConfig)
    front: FrontEnd
    if source is not None:
        front = source
    elif online:
        front = LiveFrontEnd(open_source(config.dataset, config.dataset_kind, config.cache_dir, progress=not quiet))
    else:
        front = open_frontend(config, quiet, window_fix=window_fix)
    if online != isinstance(front, LiveFrontEnd):
        raise InputError(
            f"run: {type(config).__name__} {config.name!r} cannot run on a {type(front).__name__}: "
            "an OnlineConfig runs on the live front end, a RunConfig on the cached one"
        )
    try:
        started = front.start(config)
        load_kernels(started.sampler, started.sampler_params, front.descriptor_shape)  # not in the back end's timings
        with threadpool_limits(limits=1, user_api="blas"):
            backend, clouds = _backend(started, front)
            result = front.stream(backend, quiet)
            result, record = front.record(result, clouds, sweep, sweep_off)
            return replace(result, metrics=measure(result, record))
    finally:
        front.close()


def _backend(config: RunConfig, source: FrontEnd) -> tuple[SlamBackend, Any]:
    """The SLAM core of `config` fed by `source`, and its keyframe cloud store: iSAM2, the config's cloud store and
    the memory recorder for an online run; Levenberg-Marquardt and clouds in RAM for a batch one."""
    graph: PoseGraph | IncrementalPoseGraph
    recorder: MemoryRecorder | None = None
    update_iterations = 0
    if isinstance(config, OnlineConfig):
        clouds = make_cloud_store(config.cloud_store, config.verifier.voxel_size, config.store_dir)
        graph = IncrementalPoseGraph(config.graph, final_iterations=config.update_iterations, mode=config.mode)
        update_iterations, recorder = config.update_iterations, MemoryRecorder(len(source))
    else:
        clouds = make_cloud_store("memory", config.verifier.voxel_size)
        graph = PoseGraph(config.graph, mode=config.mode)
    closer = build_loop_closer(config, source.descriptor, clouds)
    backend = build_backend(
        config,
        slam_sampler(config),
        closer,
        graph,
        len(source),
        source.name,
        update_iterations,
        recorder,
        frame_clouds=source.clouds_for(config),
    )
    return backend, clouds
