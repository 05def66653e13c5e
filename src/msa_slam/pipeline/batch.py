"""The paper's batch experiment (section V-A, Table I) end to end, for one sampler on one sequence.

odometry + descriptors (shared front end, cached) -> keyframe sampling -> loop candidates between
keyframes (descriptor similarity >= 0.8, recent keyframes excluded) -> small_gicp verification
(oracle or realistic) -> GTSAM pose graph (odometry between consecutive keyframes, verified loops, LM)
-> ATE/RPE before and after, % improvement, PR-AUC/F1-max, loop counts, memory and time.
A metric that cannot be computed (ATE of a rotation-only trajectory, PR-AUC without revisits) is None
with its reason under `unavailable`; caveats about computed ones are listed under `warnings`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from msa_slam.backend import GraphNoise, PoseGraph
from msa_slam.errors import InputError
from msa_slam.evaluation import StageTimer, TrajectoryEvaluation, evaluate_trajectories, peak_rss_bytes
from msa_slam.pipeline.config import BatchConfig
from msa_slam.pipeline.frontend import Frontend, prepare_frontend
from msa_slam.pipeline.loops import LoopCandidate, LoopSearch, search_loops, verify_candidates
from msa_slam.progress import progress_bar
from msa_slam.place_recognition import PRCurve, precision_recall
from msa_slam.registration import KeyframeCloudStore, Verifier, VerifierConfig
from msa_slam.sampling import make_sampler

BACKEND_STAGES = ("sampling", "keyframe_store", "loop_detection", "verification", "optimisation")


@dataclass
class BatchResult:
    """Everything one run produced: keyframes, trajectories, loops, metrics (JSON-ready) and timings."""

    config: BatchConfig
    frontend: Frontend
    keyframes: np.ndarray
    optimised: np.ndarray
    search: LoopSearch
    loops: list[LoopCandidate]
    pr: PRCurve | None
    ate_errors: dict[str, np.ndarray | None] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)

    @property
    def accepted_loops(self) -> list[LoopCandidate]:
        return [c for c in self.loops if c.accepted]


def sample_keyframes(config: BatchConfig, frontend: Frontend, quiet: bool = True) -> tuple[np.ndarray, dict]:
    """Keyframe frame indices (sorted) of the configured sampler on odometry (or GT) poses."""
    sampler = make_sampler(config.sampler, **config.sampler_params)
    poses = frontend.odometry if config.sample_on == "odometry" else frontend.gt_poses
    sampler.expect_frames(len(frontend))
    with progress_bar(quiet) as bar:
        task = bar.add_task(f"sampling ({config.name})", total=len(frontend))
        for i in range(len(frontend)):
            points = frontend.sequence[i].points if sampler.needs_points else None
            sampler.push(poses[i], frontend.descriptors[i], points)
            bar.advance(task)
    if config.flush:
        sampler.finish()
    keyframes = np.array(sorted(set(sampler.keyframes)), dtype=np.int64)
    stats = {**sampler.stats.as_dict(), "online_keyframes": len(sampler.online_keyframes),
             "flushed_keyframes": len(sampler.flushed_keyframes)}
    return keyframes, stats


def run_batch(config: BatchConfig, frontend: Frontend | None = None, quiet: bool = True) -> BatchResult:
    """Run one sampler through the batch protocol; pass `frontend` to reuse odometry and descriptors.

    BLAS runs single-threaded: the descriptor searches are many small matrix products, which OpenBLAS
    threads slow down ~10x on a busy 2-core machine.
    """
    if frontend is None:
        frontend = prepare_frontend(config, quiet)
    elif not frontend.matches(config):
        raise InputError("run_batch: the given front end was built with other odometry/descriptor settings")
    with threadpool_limits(limits=1, user_api="blas"):
        return _run_backend(config, frontend, quiet)


def _run_backend(config: BatchConfig, frontend: Frontend, quiet: bool) -> BatchResult:
    timer = StageTimer()
    with timer.stage("sampling"):
        keyframes, sampler_stats = sample_keyframes(config, frontend, quiet)
    if len(keyframes) < 3:
        raise InputError(f"sampler {config.name!r} kept {len(keyframes)} keyframes of {len(frontend)} frames; "
                         "the evaluation needs at least 3")
    odom, gt = frontend.odometry, frontend.gt_poses
    with timer.stage("keyframe_store"):
        clouds = KeyframeCloudStore(config.verifier.voxel_size)
        for k in keyframes:
            clouds.add(int(k), frontend.sequence[int(k)].points)
    with timer.stage("loop_detection"):
        search, database = search_loops(keyframes, frontend.descriptors, odom, gt, frontend.descriptor,
                                        config.similarity_threshold, config.min_frame_gap,
                                        config.exclude_recent, config.top_k)
    verifier = Verifier(VerifierConfig(**config.verifier.model_dump()))
    with timer.stage("verification"), progress_bar(quiet) as bar:
        task = bar.add_task(f"verification ({config.mode})", total=len(search.candidates))
        loops = verify_candidates(search.candidates, clouds, verifier, frontend.descriptor,
                                  frontend.descriptors, config.mode, config.loop_radius,
                                  advance=lambda: bar.advance(task))
    with timer.stage("optimisation"):
        g = config.graph
        graph = PoseGraph(GraphNoise(odometry_rotation=g.odometry_rotation,
                                     odometry_translation=g.odometry_translation,
                                     loop_rotation=g.loop_rotation, loop_translation=g.loop_translation,
                                     robust=g.robust, robust_threshold=g.robust_threshold),
                          max_iterations=g.max_iterations)
        for k in keyframes:
            graph.add_keyframe(int(k), odom[int(k)])
        for loop in loops:
            if loop.accepted:
                graph.add_loop(loop.match, loop.query, loop.T_match_query)
        optimised = graph.optimize()
    with timer.stage("evaluation"):
        pr = (precision_recall(search.best_similarity, search.best_distance, config.loop_radius)
              if len(search.best_similarity) else None)
        evaluation = evaluate_trajectories(odom[keyframes], optimised, gt[keyframes], keyframes)
    result = BatchResult(config, frontend, keyframes, optimised, search, loops, pr, evaluation.errors)
    result.metrics = _metrics(result, evaluation, sampler_stats, database.nbytes, clouds.nbytes,
                              graph.nbytes, timer)
    return result


def _metrics(result: BatchResult, evaluation: TrajectoryEvaluation, sampler_stats: dict, descriptor_bytes: int,
             cloud_bytes: int, graph_bytes: int, timer: StageTimer) -> dict[str, Any]:
    cfg, loops, pr = result.config, result.loops, result.pr
    accepted = [c for c in loops if c.accepted]
    backend_time = sum(timer.seconds.get(s, 0.0) for s in BACKEND_STAGES)
    frontend = result.frontend
    unavailable = dict(evaluation.metrics["unavailable"])
    if pr is None or pr.unavailable:
        unavailable["pr"] = pr.unavailable if pr is not None else (
            f"no keyframe had an older keyframe to query (more than min_frame_gap={cfg.min_frame_gap} frames back "
            f"and not among the exclude_recent={cfg.exclude_recent} newest)")
    return {
        "sequence": frontend.name,
        "dataset": cfg.dataset,
        "method": cfg.name,
        "sampler": cfg.sampler,
        "descriptor": cfg.descriptor,
        "mode": cfg.mode,
        "frames": len(frontend),
        "keyframes": int(len(result.keyframes)),
        "candidates": len(loops),
        "true_candidates": int(sum(c.gt_distance <= cfg.loop_radius for c in loops)),
        "verified": len(accepted),
        "registrations": int(sum(c.verified for c in loops)),
        "false_loops": int(sum(c.gt_distance > cfg.loop_radius for c in accepted)),
        **evaluation.metrics,
        "unavailable": unavailable,
        "warnings": [*frontend.warnings, *evaluation.warnings],
        "pr_auc": None if pr is None else pr.auc,
        "f1_max": None if pr is None else pr.f1_max,
        "pr_queries": int(len(result.search.best_similarity)),
        "memory_bytes": {
            "keyframe_descriptors": int(descriptor_bytes),
            "keyframe_clouds": int(cloud_bytes),
            "graph": int(graph_bytes),
            "total": int(descriptor_bytes + cloud_bytes + graph_bytes),
        },
        "peak_rss_bytes": peak_rss_bytes(),  # the whole process's high-water mark, not this method's
        "peak_rss_scope": "process",
        "time_s": {**{k: round(v, 4) for k, v in timer.seconds.items()}, "backend_total": round(backend_time, 4)},
        "frontend_time_s": {k: round(v, 4) for k, v in frontend.timer.seconds.items()},
        "frontend_cached": dict(frontend.cached),
        "odometry_config": frontend.odometry_effective,
        "threads": {"odometry": frontend.odometry_effective.get("registration", {}).get("max_num_threads"),
                    "verification": cfg.verifier.num_threads, "blas_backend": 1},
        "sampler_stats": sampler_stats,
    }
