"""What one SLAM run produced (batch or online): trajectories, keyframes, loops, PR curve, timings and the
metrics both protocols share, in one layout so tables and reports read either.

A metric that cannot be computed (ATE of a rotation-only trajectory, PR-AUC without revisits) is None with
its reason under `unavailable`; caveats about computed ones are listed under `warnings`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Protocol

import numpy as np

from msa_slam.evaluation import TrajectoryEvaluation, evaluate_full_rate, full_rate_poses, peak_rss_bytes
from msa_slam.evaluation.loops import account_loops
from msa_slam.place_recognition import PRCurve
from msa_slam.registration import VerifierConfig
from msa_slam.sampling.params import SamplerParams
from msa_slam.slam.loop_closing import REJECTION_REASONS, loop_summary
from msa_slam.types import LoopClosure


class RunSettings(Protocol):
    """The fields of a run's configuration the core reads (msa_slam.pipeline.config.RunConfig)."""

    dataset: str
    sampler: str
    sampler_params: SamplerParams
    verifier: VerifierConfig
    descriptor: str
    descriptor_params: dict[str, Any]
    mode: str
    sample_on: str
    flush: bool
    similarity_threshold: float
    min_frame_gap: int
    exclude_recent: int
    top_k: int
    loop_radius: float
    min_travel_m: float
    loop_detector: str
    local_map_m: float

    @property
    def name(self) -> str: ...


@dataclass
class RunResult:
    """Everything one run produced. Per-frame arrays cover every frame (`times` are the frames' own);
    `optimised` holds the keyframes' poses; `steps_ms` the back-end's per-frame step times (online adds
    odometry and descriptor) and `memory` online's per-frame memory series."""

    config: Any
    name: str
    times: np.ndarray
    odometry: np.ndarray
    gt_poses: np.ndarray
    keyframes: np.ndarray
    optimised: np.ndarray
    loops: list[LoopClosure]
    pr: PRCurve | None
    evaluation: TrajectoryEvaluation
    steps_ms: dict[str, np.ndarray]
    memory_bytes: dict[str, int]
    sampler_stats: dict[str, Any]
    pr_queries: int  # keyframes that had an older keyframe to query (points of the PR curve)
    final_s: dict[str, float] = field(default_factory=dict)  # optimisation, evaluation and map at the end
    memory: dict[str, np.ndarray] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    pr_reference: PRCurve | None = None  # the reference example's protocol (batch runs; None: not computed)
    map_points: np.ndarray | None = None  # keyframe clouds at the optimised poses, voxel-merged (world)
    descriptors: np.ndarray | None = None  # per-frame descriptors, when the pipeline kept them (batch)
    graph_factors: Any = None  # the pose graph's factors (gtsam.NonlinearFactorGraph), for pose_graph.g2o
    rss_growth_bytes: int = 0  # process RSS after the final optimisation minus at the back-end's start
    graph_info: dict[str, Any] = field(default_factory=dict)  # how loops entered the graph (Graph.describe)

    @property
    def accepted_loops(self) -> list[LoopClosure]:
        return [c for c in self.loops if c.accepted]

    @property
    def backend_ms(self) -> np.ndarray:
        """Per-frame time of everything after odometry (ms)."""
        return sum(v for s, v in self.steps_ms.items() if s != "odometry")

    @cached_property
    def optimised_full(self) -> np.ndarray:
        """Every frame's pose after optimisation: its preceding keyframe's optimised pose and the odometry
        between them (evaluation.full_rate)."""
        return full_rate_poses(self.odometry, self.keyframes, self.optimised)

    @property
    def ate_errors(self) -> dict[str, np.ndarray | None]:
        return self.evaluation.errors

    def __len__(self) -> int:
        return len(self.odometry)


def core_metrics(result: RunResult) -> dict[str, Any]:
    """The metrics both protocols report: counts, loops (and their accounting against ground truth,
    evaluation.loops), keyframe and full-rate ATE/RPE, PR, accounted memory, sampler statistics."""
    cfg, loops, ev = result.config, result.loops, result.evaluation
    accepted = result.accepted_loops
    unavailable = dict(ev.metrics["unavailable"])
    accounting = account_loops(loops, result.keyframes, result.gt_poses, cfg.loop_radius, cfg.min_travel_m,
                               REJECTION_REASONS)
    unavailable.update(accounting.unavailable)
    pr = result.pr
    if pr is None or pr.unavailable:
        unavailable["pr"] = pr.unavailable if pr is not None else (
            f"no keyframe had an older keyframe to query (more than min_frame_gap={cfg.min_frame_gap} frames back "
            f"and not among the exclude_recent={cfg.exclude_recent} newest)")
    full_rate = evaluate_full_rate(result.odometry, result.optimised_full, result.gt_poses)
    unavailable.update(full_rate.pop("unavailable"))
    mem = result.memory_bytes
    clouds = mem["cloud_bytes"] + mem["cloud_disk_bytes"]
    # what the run keeps in RAM, for the RSS growth: SLAM memory without on-disk clouds, records and the map
    local_map = mem.get("local_map_bytes", 0)  # the recent scans a local-map loop detector keeps (else absent)
    in_ram = (mem["descriptor_bytes"] + mem["cloud_bytes"] + mem["graph_bytes"] + local_map + mem["record_bytes"]
              + mem["map_bytes"])
    return {
        "sequence": result.name, "dataset": cfg.dataset, "method": cfg.name, "sampler": cfg.sampler,
        "descriptor": cfg.descriptor, "mode": cfg.mode, "frames": len(result), "keyframes": int(len(result.keyframes)),
        "candidates": accounting.candidates, "true_candidates": accounting.true_candidates,
        "verified": accounting.accepted, "registrations": accounting.registered,
        "false_loops": int(sum(c.gt_distance > cfg.loop_radius for c in accepted)),
        "loop_closing": loop_summary(loops, cfg, result.graph_info),
        "loop_accounting": accounting.as_dict(),
        **ev.metrics,
        "full_rate": full_rate,
        "unavailable": unavailable,
        "warnings": list(ev.warnings),
        "pr_auc": None if pr is None else pr.auc,
        "f1_max": None if pr is None else pr.f1_max,
        "pr_queries": result.pr_queries,
        "memory_bytes": {"keyframe_descriptors": mem["descriptor_bytes"], "keyframe_clouds": clouds,
                         "graph": mem["graph_bytes"],
                         **({"local_map": local_map} if "local_map_bytes" in mem else {}),
                         "total": mem["descriptor_bytes"] + clouds + mem["graph_bytes"] + local_map,
                         "run_records": mem["record_bytes"], "map": mem["map_bytes"], "in_ram": in_ram},
        "peak_rss_bytes": peak_rss_bytes(),  # the whole process's high-water mark, not this run's
        "peak_rss_scope": "process",
        "rss_growth_bytes": int(result.rss_growth_bytes),
        "rss_growth_ratio": round(result.rss_growth_bytes / in_ram, 3) if in_ram else None,
        "sampler_stats": result.sampler_stats,
    }
