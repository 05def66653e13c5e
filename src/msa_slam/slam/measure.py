"""The one place a run's report (evaluation.metrics.RunMetrics) is built, batch and online alike: the metrics the
SLAM core measures for both (counts, loops and their accounting, keyframe and full-rate ATE/RPE, PR, accounted
memory, sampler statistics) joined with what the protocol measured around it (evaluation.metrics.ProtocolRecord).
"""

from __future__ import annotations

from msa_slam.evaluation import peak_rss_bytes
from msa_slam.evaluation.loops import account_loops
from msa_slam.evaluation.metrics import (
    NOTHING_IN_RAM,
    AccountedMemory,
    Loops,
    Memory,
    PlaceRecognition,
    ProtocolRecord,
    RunIdentity,
    Unavailable,
)
from msa_slam.evaluation.metrics_reader import MetricsDocument
from msa_slam.evaluation.run_metrics import RunMetrics
from msa_slam.slam.loop_closing import REJECTION_REASONS, loop_summary
from msa_slam.slam.result import RunResult


def _no_queries(min_frame_gap: int, exclude_recent: int) -> str:
    return (
        f"no keyframe had an older keyframe to query (more than min_frame_gap={min_frame_gap} frames back "
        f"and not among the exclude_recent={exclude_recent} newest)"
    )


def _memory(result: RunResult, cloud_store: str | None, peak: int) -> Memory:
    """Accounted bytes by part (docs/metrics.md, "Memory") beside the process's RSS figures."""
    mem = result.memory_bytes
    clouds = mem["cloud_bytes"] + mem["cloud_disk_bytes"]
    # what the run keeps in RAM, for the RSS growth: SLAM memory without on-disk clouds, records and the map
    local_map = mem.get("local_map_bytes")  # the recent scans a local-map loop detector keeps (else absent)
    kept = local_map or 0
    in_ram = (
        mem["descriptor_bytes"]
        + mem["cloud_bytes"]
        + mem["graph_bytes"]
        + kept
        + mem["record_bytes"]
        + mem["map_bytes"]
    )
    accounted = AccountedMemory(
        mem["descriptor_bytes"],
        clouds,
        mem["graph_bytes"],
        local_map,
        mem["descriptor_bytes"] + clouds + mem["graph_bytes"] + kept,
        mem["record_bytes"],
        mem["map_bytes"],
        in_ram,
        mem["cloud_disk_bytes"] if cloud_store else None,
        cloud_store,
    )
    ratio = round(result.rss_growth_bytes / in_ram, 3) if in_ram else Unavailable(NOTHING_IN_RAM)
    return Memory(accounted, peak, "process", int(result.rss_growth_bytes), ratio)


def measure(result: RunResult, protocol: ProtocolRecord) -> RunMetrics:
    """The report of `result` (a run's back end, finished) with what its protocol measured around it."""
    cfg, ev, pr = result.config, result.evaluation, result.pr
    # peak RSS: the whole process's high-water mark, not this run's
    peak = peak_rss_bytes() if protocol.peak_rss_bytes is None else protocol.peak_rss_bytes
    accounting, loop_reasons = account_loops(
        result.loops, result.keyframes, result.gt_poses, cfg.loop_radius, cfg.min_travel_m, REJECTION_REASONS
    )
    reasons = dict(ev.reasons)
    reasons.update(loop_reasons)
    if pr is None or pr.unavailable:
        reasons["pr"] = pr.unavailable if pr is not None else _no_queries(cfg.min_frame_gap, cfg.exclude_recent)
    full_rate = result.full_rate_evaluation
    reasons.update(full_rate.reasons)
    reasons.update(protocol.reasons)
    values = MetricsDocument(
        {"pr_auc": None if pr is None else pr.auc, "f1_max": None if pr is None else pr.f1_max},
        "the run",
        reasons=reasons,
    )
    loops = Loops(
        accounting.candidates,
        accounting.true_candidates,
        accounting.accepted,
        accounting.registered,
        loop_summary(result.loops, cfg, result.graph_info),
        accounting,
    )
    place = PlaceRecognition(
        values.value("pr_auc", "pr"),
        values.value("f1_max", "pr"),
        result.pr_queries,
        protocol.reference,
        protocol.sweep,
    )
    run = RunIdentity(
        result.name,
        cfg.dataset,
        cfg.name,
        cfg.sampler,
        cfg.descriptor,
        cfg.mode,
        len(result),
        int(len(result.keyframes)),
    )
    return RunMetrics(
        protocol.pipeline,
        run,
        loops,
        ev.trajectory,
        full_rate.trajectory,
        reasons,
        (*protocol.warnings, *ev.warnings),
        place,
        _memory(result, protocol.cloud_store, peak),
        dict(result.sampler_stats),
        protocol.timing,
        protocol.setup,
        protocol.throughput,
    )
