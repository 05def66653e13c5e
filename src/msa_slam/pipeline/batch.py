"""The paper's batch experiment (section V-A, Table I) end to end, for one sampler on one sequence.

odometry + descriptors (shared front end, cached) streamed frame by frame through the SLAM core
(msa_slam.slam: keyframe sampling, loop candidates between keyframes with descriptor similarity >= 0.8 and
recent keyframes excluded, small_gicp verification (oracle or realistic)) -> GTSAM pose graph optimised
once with Levenberg-Marquardt at the end -> ATE/RPE before and after (keyframes and full rate), %
improvement, PR-AUC/F1-max of both place-recognition protocols, loop counts, memory and time, and the
threshold sweep (the back-end re-run at similarity thresholds around the run's, experiments/sweep.py).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Mapping

import numpy as np
from threadpoolctl import threadpool_limits

from msa_slam.backend import PoseGraph
from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import BATCH, JSONValue, ReferencePR, RunSetup, SweepRow, Timing, Unavailable
from msa_slam.evaluation.metrics_reader import NO_REASON
from msa_slam.evaluation.resources import peak_rss_bytes
from msa_slam.pipeline.config import RunConfig
from msa_slam.pipeline.frontend import CONFIG_WINDOW_FIX, Frontend, config_as_run, prepare_frontend
from msa_slam.experiments.sweep import threshold_sweep
from msa_slam.slam.loop_closing import protocol
from msa_slam.place_recognition import PRCurve, precision_recall
from msa_slam.place_recognition.metrics import reference_protocol_matches
from msa_slam.progress import progress_bar
from msa_slam.registration import KeyframeCloudStore
from msa_slam.sampling.msa.warm import load_kernels
from msa_slam.slam import (BACKEND_STEPS, ProtocolRecord, RunResult, build_backend, build_loop_closer, measure,
                           slam_sampler)

BACKEND_STAGES = (*BACKEND_STEPS, "optimisation")
SWEEP_NOT_RUN = "not run: left out with `--no-sweep` (the demo leaves it out to stay short)"
RUN_SWEEP_NOT_RUN = "not run (an analysis, not part of the run: pass `--sweep` to add it)"


def run_batch(config: RunConfig, frontend: Frontend | None = None, quiet: bool = True,
              sweep: bool = True, window_fix: str = CONFIG_WINDOW_FIX, sweep_off: str = SWEEP_NOT_RUN) -> RunResult:
    """Run one sampler through the batch protocol; pass `frontend` to reuse odometry and descriptors;
    `sweep=False` leaves out the threshold sweep (unavailable in the report; `sweep_off`: its reason, which names
    the command's way to add it). A front end built here
    first refuses a sampler window the frames read never fill (prepare_frontend; `window_fix`: what the
    error says to change).

    BLAS runs single-threaded: the descriptor searches are many small matrix products, which OpenBLAS
    threads slow down ~10x on a busy 2-core machine.
    """
    if frontend is None:
        frontend = prepare_frontend(config, quiet, window_fix=window_fix)
    elif not frontend.matches(config):
        raise InputError("run_batch: the given front end was built with other odometry/descriptor settings")
    config = config_as_run(config, frontend.sequence.point_times)  # what result.config (config.yaml) records
    load_kernels(config.sampler, config.sampler_params, frontend.descriptors.shape[1:])  # not in the timings
    with threadpool_limits(limits=1, user_api="blas"):
        return _run_backend(config, frontend, quiet, sweep, sweep_off)


def _run_backend(config: RunConfig, frontend: Frontend, quiet: bool, sweep: bool, sweep_off: str) -> RunResult:
    graph = PoseGraph(config.graph, mode=config.mode)
    clouds = KeyframeCloudStore(config.verifier.voxel_size)
    backend = build_backend(config, slam_sampler(config), build_loop_closer(config, frontend.descriptor, clouds), graph,
                            len(frontend), frontend.name, frame_clouds=frontend.clouds_for(config))
    sequence, times, gt = frontend.sequence, frontend.sequence.times, frontend.gt_poses
    with progress_bar(quiet) as bar:
        task = bar.add_task(f"back-end ({config.name})", total=len(frontend))
        for i in range(len(frontend)):
            backend.add_frame(frontend.odometry[i], frontend.descriptors[i], lambda i=i: sequence[i].points,
                              None if gt is None else gt[i], times[i])
            bar.advance(task)
    result = backend.finish()
    sims, dists = (reference_protocol_matches(frontend.descriptor, result.keyframes, frontend.descriptors, gt)
                   if gt is not None else ([], []))
    result = replace(result, descriptors=frontend.descriptors[:len(result)],
                     pr_reference=precision_recall(sims, dists, config.loop_radius) if len(sims) else None)
    reasons = {}
    fraction, why = sampler_realtime_fraction(result.sampler_stats, result.times, frontend.sequence.times_known)
    if why is not None:
        reasons["sampler_realtime_fraction"] = why
    reasons["pr_reference"] = _reference_reason(result.pr_reference, gt is not None)
    peak = peak_rss_bytes()  # the run's, without the sweep's replays
    rows, seconds = _sweep(result, frontend, clouds, sweep, sweep_off, reasons)
    reference = _reference(result.pr_reference, reasons["pr_reference"], len(sims))
    record = ProtocolRecord(BATCH, tuple(frontend.warnings), _timing(result, frontend, fraction, why, seconds),
                            RunSetup(frontend.deskew, _threads(config, frontend), frontend.odometry_effective),
                            {k: v for k, v in reasons.items() if v is not None}, reference, rows,
                            peak_rss_bytes=peak)
    return replace(result, metrics=measure(result, record))


def _sweep(result: RunResult, frontend: Frontend, clouds: KeyframeCloudStore, sweep: bool, sweep_off: str,
           reasons: dict[str, str | None]) -> tuple[tuple[SweepRow, ...] | Unavailable, float | None]:
    """The threshold sweep's rows and seconds, or why it did not run (also put into `reasons`)."""
    if result.gt_poses is None:
        reasons["threshold_sweep"] = "no ground truth: ATE improvement is undefined"
    if not sweep:
        reasons["threshold_sweep"] = sweep_off
    elif protocol(result.config) != "paper":
        reasons["threshold_sweep"] = ("the verified loop protocol does not use similarity_threshold (its floor: "
                                      "verified_min_similarity)")
    elif result.gt_poses is not None:
        start = time.perf_counter()
        rows = threshold_sweep(result, frontend, clouds)
        return rows, round(time.perf_counter() - start, 4)  # not in backend_total
    return Unavailable(reasons["threshold_sweep"]), None


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
        return ("no frame had more than 10 keyframes before it and a best match more than 10 frames away (the "
                "reference protocol recorded no match)")
    return pr.unavailable or None


def sampler_realtime_fraction(sampler_stats: Mapping[str, JSONValue], times: np.ndarray,
                              times_known: bool) -> tuple[float | None, str | None]:
    """The sampler's window optimisations' total time over the duration of the data it sampled (the frames'
    first to last timestamp): the share of a real-time budget sampling alone takes. None with the reason when
    the frames have no timestamps (`times_known` False: their times are frame numbers, 1 frame/s) or span no
    time."""
    if not times_known:
        return None, "the frames have no timestamps, so the data's duration is unknown"
    span = float(times[-1] - times[0]) if len(times) > 1 else 0.0
    if not span > 0:
        return None, "the frames' timestamps span no time"
    return sampler_stats["optimisation_ms_total"] / 1e3 / span, None


def _timing(result: RunResult, frontend: Frontend, fraction: float | None, why: str | None,
            sweep_s: float | None) -> Timing:
    """Seconds per back-end stage (the sweep's last, not in backend_total), the front end's, and the sampler's share
    of real time."""
    times = {s: float(result.steps_ms[s].sum()) / 1e3 for s in BACKEND_STEPS}
    times.update(result.final_s)
    backend_time = sum(times.get(s, 0.0) for s in BACKEND_STAGES)
    stages = {**{k: round(v, 4) for k, v in times.items()}, "backend_total": round(backend_time, 4),
              "threshold_sweep": sweep_s}
    return Timing(stages, {k: round(v, 4) for k, v in frontend.replayed_s.items()},
                  {k: round(v, 4) for k, v in frontend.timer.seconds.items()}, dict(frontend.cached),
                  Unavailable(why) if fraction is None else fraction)


def _threads(config: RunConfig, frontend: Frontend) -> dict[str, int | None]:
    return {"odometry": frontend.odometry_effective.get("registration", {}).get("max_num_threads"),
            "verification": config.verifier.num_threads, "blas_backend": 1}
