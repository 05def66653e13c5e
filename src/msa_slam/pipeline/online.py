"""The paper's online experiment (section V-B, Table II): frames one by one, as on a robot.

Each frame: odometry -> descriptor -> sampler.push. Every keyframe the sampler finalises is stored
(odometry pose, descriptor, voxel-downsampled cloud in RAM or on disk), queried against the past
keyframes (descriptor similarity >= 0.8, recent keyframes excluded; the best match feeds the PR curve),
its candidates verified (small_gicp, or the ground-truth oracle as in the paper) and added to an iSAM2
graph (Kaess et al., IJRR 2012) that is updated at that frame. Per frame it records the time of each step
and the memory held (keyframe clouds, descriptors, graph, process RSS); at the end F1-max, ATE before
and after optimisation, and throughput (frames per second, real-time factor for the sensor rate).
"""

from __future__ import annotations

import os
import time
from contextlib import closing
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from threadpoolctl import threadpool_limits

from msa_slam.backend import GraphNoise, IncrementalPoseGraph
from msa_slam.datasets import Frame
from msa_slam.descriptors import make_descriptor
from msa_slam.errors import InputError
from msa_slam.evaluation import TrajectoryEvaluation, evaluate_trajectories, peak_rss_bytes
from msa_slam.odometry import OdometryCache
from msa_slam.pipeline.frontend import make_odometry, pipeline_cache
from msa_slam.pipeline.loops import LoopCandidate, verify_candidates
from msa_slam.pipeline.online_config import OnlineConfig
from msa_slam.pipeline.online_source import FrameSource, NoisyOdometry, open_source
from msa_slam.pipeline.online_store import make_cloud_store
from msa_slam.place_recognition import KeyframeDatabase, PRCurve, precision_recall
from msa_slam.registration import Verifier, VerifierConfig
from msa_slam.sampling import make_sampler

STEPS = ("odometry", "descriptor", "sampling", "keyframe_store", "loop_detection", "verification", "graph_update")
BACKEND_STEPS = STEPS[1:]  # everything after odometry
MEMORY = ("keyframes", "cloud_bytes", "cloud_disk_bytes", "descriptor_bytes", "graph_bytes", "pending_bytes",
          "rss_bytes")


def current_rss_bytes() -> int:
    """Resident set size now (Linux /proc/self/statm); the peak where that is unavailable."""
    try:
        with open("/proc/self/statm") as handle:
            return int(handle.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError, AttributeError):
        return peak_rss_bytes()


@dataclass
class OnlineResult:
    """What an online run produced: per-frame records, keyframes, optimised poses, loops and metrics."""

    config: OnlineConfig
    name: str
    odometry: np.ndarray
    gt_poses: np.ndarray
    keyframes: np.ndarray
    optimised: np.ndarray
    loops: list[LoopCandidate]
    pr: PRCurve | None
    steps_ms: dict[str, np.ndarray]
    memory: dict[str, np.ndarray]
    ate_errors: dict[str, np.ndarray] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)

    @property
    def accepted_loops(self) -> list[LoopCandidate]:
        return [c for c in self.loops if c.accepted]

    @property
    def backend_ms(self) -> np.ndarray:
        """Per-frame time of everything after odometry (ms)."""
        return sum(self.steps_ms[s] for s in BACKEND_STEPS)


class OnlinePipeline:
    """Frame-by-frame SLAM back-end; `step(frame)` per scan, then `finish()` -> OnlineResult."""

    def __init__(self, config: OnlineConfig, odometry, n_frames: int, name: str = "sequence") -> None:
        self.config = config
        self.name = name
        self.odometry_source = odometry
        self.descriptor = make_descriptor(config.descriptor, **config.descriptor_params)
        self.sampler = make_sampler(config.sampler, **config.sampler_params)
        self.database = KeyframeDatabase(self.descriptor)
        self.clouds = make_cloud_store(config.cloud_store, config.verifier.voxel_size, config.store_dir)
        self.verifier = Verifier(VerifierConfig(**config.verifier.model_dump()))
        g = config.graph
        self.graph = IncrementalPoseGraph(GraphNoise(
            odometry_rotation=g.odometry_rotation, odometry_translation=g.odometry_translation,
            loop_rotation=g.loop_rotation, loop_translation=g.loop_translation, robust=g.robust,
            robust_threshold=g.robust_threshold))
        self.n = int(n_frames)
        self.sampler.expect_frames(self.n)
        self.odom = np.zeros((self.n, 4, 4))
        self.gt = np.zeros((self.n, 4, 4))
        self.steps_ms = {s: np.zeros(self.n, dtype=np.float32) for s in STEPS}
        self.memory = {m: np.zeros(self.n, dtype=np.int64) for m in MEMORY}
        self.loops: list[LoopCandidate] = []
        self.best_similarity: list[float] = []
        self.best_distance: list[float] = []
        self._pending: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # frames the sampler may still choose
        self._keyframes: list[int] = []
        self._row: dict[int, int] = {}  # keyframe -> row in the database
        self._frames = 0

    def __len__(self) -> int:
        return self._frames

    @property
    def keyframes(self) -> list[int]:
        return list(self._keyframes)

    def step(self, frame: Frame) -> list[int]:
        """Process the next scan; return the keyframes finalised by it (frame indices)."""
        i = self._frames
        if i >= self.n:
            raise InputError(f"online pipeline: frame {i} beyond the announced {self.n} frames")
        if frame.gt_pose is None:
            raise InputError(f"online pipeline: frame {i} has no ground-truth pose (needed for oracle loops, ATE)")
        ms = self.steps_ms
        t0 = time.perf_counter()
        self.odom[i] = self.odometry_source.register(frame.points)
        t1 = time.perf_counter()
        desc = np.asarray(self.descriptor.compute(frame.points, frame=i), dtype=np.float64)
        t2 = time.perf_counter()
        self.gt[i] = frame.gt_pose
        self._pending[i] = (desc, frame.points)
        new = self.sampler.push(self.odom[i], desc, frame.points if self.sampler.needs_points else None)
        t3 = time.perf_counter()
        ms["odometry"][i], ms["descriptor"][i], ms["sampling"][i] = (t1 - t0) * 1e3, (t2 - t1) * 1e3, (t3 - t2) * 1e3
        self._frames += 1
        self._add_keyframes(new, i)
        self._prune()
        self._record_memory(i)
        return new

    def _timed(self, name: str, i: int, start: float) -> float:
        now = time.perf_counter()
        self.steps_ms[name][i] += (now - start) * 1e3
        return now

    def _add_keyframes(self, new: list[int], i: int) -> None:
        cfg = self.config
        accepted_any = False
        for k in new:
            k = int(k)
            if k not in self._pending:
                raise RuntimeError(f"sampler {self.config.sampler!r} chose frame {k} at frame {i}, but frame {k} "
                                   "had left its window (online keyframes must be window members)")
            desc, points = self._pending.pop(k)
            t = time.perf_counter()
            self.clouds.add(k, points)
            self.graph.add_keyframe(k, self.odom[k])
            t = self._timed("keyframe_store", i, t)
            matches = self.database.query(k, desc, exclude_frames=cfg.min_frame_gap,
                                          exclude_recent=cfg.exclude_recent, threshold=0.0, top_k=cfg.top_k)
            candidates = []
            for rank, match in enumerate(matches):
                dist = float(np.linalg.norm(self.gt[k, :3, 3] - self.gt[match.keyframe_id, :3, 3]))
                if rank == 0:
                    self.best_similarity.append(match.similarity)
                    self.best_distance.append(dist)
                if match.similarity >= cfg.similarity_threshold:
                    candidates.append(LoopCandidate(k, match.keyframe_id, match.similarity, dist))
            self._row[k] = len(self.database)
            self.database.add(k, self.odom[k], desc)
            t = self._timed("loop_detection", i, t)
            if candidates:
                descs = {c.match: self.database.descriptors[self._row[c.match]] for c in candidates}
                descs[k] = desc
                verified = verify_candidates(candidates, self.clouds, self.verifier, self.descriptor, descs,
                                             cfg.mode, cfg.loop_radius)
                for loop in verified:
                    if loop.accepted:
                        self.graph.add_loop(loop.match, loop.query, loop.T_match_query)
                        accepted_any = True
                self.loops.extend(verified)
                self._timed("verification", i, t)
            self._keyframes.append(k)
        if new:
            t = time.perf_counter()
            self.graph.update(cfg.update_iterations if accepted_any else 0)
            self._timed("graph_update", i, t)

    def _prune(self) -> None:
        """Forget buffered frames the sampler can no longer choose, so pending scans stay bounded however
        the robot moves: only members of MSA's window (at most N + 1 frames) may still become keyframes;
        a frame the window skipped (it moved < MIN_WINDOW_STEP, e.g. standing still) never joins it later,
        and samplers without a window decide each frame as it arrives."""
        selectable = set(getattr(self.sampler, "window", ()))
        for f in [f for f in self._pending if f not in selectable]:
            del self._pending[f]

    def _record_memory(self, i: int) -> None:
        mem = self.memory
        mem["keyframes"][i] = len(self._keyframes)
        mem["cloud_bytes"][i] = self.clouds.nbytes
        mem["cloud_disk_bytes"][i] = getattr(self.clouds, "disk_bytes", 0)
        mem["descriptor_bytes"][i] = self.database.nbytes
        mem["graph_bytes"][i] = self.graph.nbytes
        mem["pending_bytes"][i] = sum(d.nbytes + p.nbytes for d, p in self._pending.values())
        mem["rss_bytes"][i] = current_rss_bytes()

    def finish(self) -> OnlineResult:
        """Flush the sampler (if configured), run the final iSAM2 iterations and evaluate."""
        n = self._frames
        if n < self.n:  # a shorter stream than announced
            self.odom, self.gt = self.odom[:n], self.gt[:n]
            self.steps_ms = {k: v[:n] for k, v in self.steps_ms.items()}
            self.memory = {k: v[:n] for k, v in self.memory.items()}
        if self.config.flush and n:
            self._add_keyframes(self.sampler.finish(), n - 1)
            self._record_memory(n - 1)
        if len(self._keyframes) < 3:
            raise InputError(f"sampler {self.config.name!r} kept {len(self._keyframes)} keyframes of {n} frames; "
                             "the evaluation needs at least 3")
        t = time.perf_counter()
        optimised = self.graph.optimize(self.config.update_iterations)
        final_ms = (time.perf_counter() - t) * 1e3
        keys = np.array(self.graph.keys, dtype=np.int64)
        pr = (precision_recall(self.best_similarity, self.best_distance, self.config.loop_radius)
              if self.best_similarity else None)
        result = OnlineResult(self.config, self.name, self.odom, self.gt, keys, optimised, self.loops, pr,
                              self.steps_ms, self.memory)
        evaluation = evaluate_trajectories(self.odom[keys], optimised, self.gt[keys], keys)
        result.ate_errors = evaluation.errors
        result.metrics = _metrics(result, evaluation, self.sampler.stats.as_dict(), final_ms,
                                  getattr(self.clouds, "disk_bytes", 0))
        result.metrics["pr_queries"] = len(self.best_similarity)
        self.close()
        return result

    def close(self) -> None:
        """Release the keyframe clouds (a disk store removes the files it wrote); safe to call twice."""
        close = getattr(self.clouds, "close", None)
        if close is not None:
            close()


def _percentiles(values: np.ndarray) -> dict[str, float]:
    v = np.asarray(values, dtype=np.float64)
    if not v.size:
        return {"p50": 0.0, "p95": 0.0, "p99": 0.0, "max": 0.0}
    p50, p95, p99 = np.percentile(v, [50, 95, 99])
    return {"p50": round(float(p50), 3), "p95": round(float(p95), 3), "p99": round(float(p99), 3),
            "max": round(float(v.max()), 3)}


def _metrics(result: OnlineResult, evaluation: TrajectoryEvaluation, sampler_stats: dict, final_ms: float,
             disk_bytes: int) -> dict[str, Any]:
    """Metrics in the batch pipeline's layout (so tables and reports read both) plus online extras."""
    cfg, loops, mem = result.config, result.loops, result.memory
    accepted = result.accepted_loops
    n = len(result.odometry)
    totals = {s: float(result.steps_ms[s].sum()) / 1e3 for s in STEPS}
    backend = float(result.backend_ms.sum()) / 1e3 + final_ms / 1e3
    wall = backend + totals["odometry"]
    k = len(result.keyframes)
    cloud_bytes = int(mem["cloud_bytes"][-1]) + int(disk_bytes)
    desc_bytes, graph_bytes = int(mem["descriptor_bytes"][-1]), int(mem["graph_bytes"][-1])
    unavailable = dict(evaluation.metrics["unavailable"])
    if result.pr is None or result.pr.unavailable:
        unavailable["pr"] = result.pr.unavailable if result.pr is not None else (
            f"no keyframe had an older keyframe to query (more than min_frame_gap={cfg.min_frame_gap} frames back)")
    graph_steps = result.steps_ms["graph_update"][mem["keyframes"] > np.concatenate([[0], mem["keyframes"][:-1]])]
    return {
        "pipeline": "online",
        "sequence": result.name, "dataset": cfg.dataset, "method": cfg.name, "sampler": cfg.sampler,
        "descriptor": cfg.descriptor, "mode": cfg.mode, "frames": n, "keyframes": k,
        "candidates": len(loops),
        "true_candidates": int(sum(c.gt_distance <= cfg.loop_radius for c in loops)),
        "verified": len(accepted), "registrations": int(sum(c.verified for c in loops)),
        "false_loops": int(sum(c.gt_distance > cfg.loop_radius for c in accepted)),
        **evaluation.metrics,
        "unavailable": unavailable,
        "warnings": list(evaluation.warnings),
        "pr_auc": None if result.pr is None else result.pr.auc,
        "f1_max": None if result.pr is None else result.pr.f1_max,
        "memory_bytes": {"keyframe_descriptors": desc_bytes, "keyframe_clouds": cloud_bytes, "graph": graph_bytes,
                         "total": desc_bytes + cloud_bytes + graph_bytes,
                         "keyframe_clouds_on_disk": int(disk_bytes), "cloud_store": cfg.cloud_store},
        "bytes_per_keyframe": (desc_bytes + cloud_bytes + graph_bytes) / k,
        "peak_rss_bytes": peak_rss_bytes(),  # the whole process's high-water mark, not this run's
        "peak_rss_scope": "process",
        "time_s": {**{s: round(v, 4) for s, v in totals.items()}, "final_optimisation": round(final_ms / 1e3, 4),
                   "backend_total": round(backend, 4)},
        "fps": n / wall if wall > 0 else float("inf"),
        "backend_fps": n / backend if backend > 0 else float("inf"),
        "realtime_factor": (n / wall) / cfg.sensor_rate_hz if wall > 0 else float("inf"),
        "latency_ms": {"backend": _percentiles(result.backend_ms),
                       **{s: _percentiles(result.steps_ms[s]) for s in STEPS},
                       "graph_update_per_keyframe_step": _percentiles(graph_steps)},
        "sampler_stats": sampler_stats,
    }


def make_online_odometry(config: OnlineConfig, source: FrameSource, n: int):
    """(odometry object, cached) - gt-noise, a pose file, or KISS-ICP (replayed from the batch pipeline's
    per-sequence cache when it has this sequence, so grids do not redo it; live otherwise)."""
    if config.odometry == "gt-noise":
        try:
            return NoisyOdometry(source.gt_poses[:n], seed=config.seed, **config.odometry_params), False
        except TypeError:
            raise InputError(f"odometry gt-noise: bad parameters {sorted(config.odometry_params)}; it takes "
                             "translation_noise, rotation_noise_deg") from None
    odometry = make_odometry(config, len(source))
    if config.odometry == "kiss" and source.path is not None:
        cached = OdometryCache(pipeline_cache(config)).load(OdometryCache.key(source.path, odometry.config),
                                                            len(source))
        if cached is not None:
            return _Replay(cached), True
    return odometry, False


class _Replay:
    """Odometry poses computed earlier for this sequence, handed out frame by frame."""

    def __init__(self, poses: np.ndarray) -> None:
        self.poses, self._i = poses, 0

    def register(self, points=None, timestamps=None) -> np.ndarray:
        self._i += 1
        return self.poses[self._i - 1]


def online_progress(quiet: bool) -> Progress:
    """Progress bar with frames per second and real-time factor."""
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("{task.fields[fps]:6.1f} fps  RTF {task.fields[rtf]:5.2f}x  "
                               "kf {task.fields[kf]}  loops {task.fields[loops]}"),
                    TimeElapsedColumn(), disable=quiet, transient=False)


def run_online(config: OnlineConfig, source: FrameSource | None = None, quiet: bool = True) -> OnlineResult:
    """Run the online pipeline over a source (by default the config's dataset); BLAS single-threaded as in
    the batch pipeline (many small matrix products)."""
    source = source or open_source(config.dataset, config.dataset_kind, config.cache_dir, progress=not quiet)
    n = len(source) if config.max_frames is None else min(len(source), config.max_frames)
    odometry, cached = make_online_odometry(config, source, n)
    pipe = OnlinePipeline(config, odometry, n, source.name)
    with threadpool_limits(limits=1, user_api="blas"), online_progress(quiet) as bar, closing(pipe):
        task = bar.add_task(f"online {config.name}", total=n, fps=0.0, rtf=0.0, kf=0, loops=0)
        start = time.perf_counter()
        for i, frame in enumerate(source.frames()):
            if i >= n:
                break
            pipe.step(frame)
            if not quiet and (i % 10 == 9 or i == n - 1):
                fps = (i + 1) / max(time.perf_counter() - start, 1e-9)
                bar.update(task, completed=i + 1, fps=fps, rtf=fps / config.sensor_rate_hz,
                           kf=len(pipe.keyframes), loops=sum(c.accepted for c in pipe.loops))
        result = pipe.finish()
    result.metrics["odometry_cached"] = cached
    return result
