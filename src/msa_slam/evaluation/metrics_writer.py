"""RunMetrics -> metrics.json: `to_json` writes the keys in the order and form metrics.json has always had
(docs/metrics.md), with its stamp when the report has one. Its inverse is evaluation.metrics_json.from_json; the
two are kept apart because writing needs only the report's fields, reading checks every key and type.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from msa_slam.evaluation.metrics import ONLINE, FullRateErrors, JSONValue, KeyframeErrors, Memory, Unavailable
from msa_slam.evaluation.run_metrics import RunMetrics


def _none(value: Any) -> Any:
    """A value as JSON holds it: null for an unavailable one."""
    return None if isinstance(value, Unavailable) else value


def _fields(obj: Any, names: tuple[str, ...]) -> dict[str, JSONValue]:
    return {name: _none(getattr(obj, name)) for name in names}


KEYFRAME_ERRORS = tuple(f.name for f in fields(KeyframeErrors))  # metrics.json's keys, in the dataclasses' order
FULL_RATE_ERRORS = tuple(f.name for f in fields(FullRateErrors))
IMPROVEMENT = ("translation", "rotation")
SWEEP_ROW = ("threshold", "candidates", "loops_accepted", "false_loops", "ate_after_m", "improvement_t_pct")
# loop_accounting's keys; its false_loops is the top-level "false_loops" (one key)
ACCOUNTING = (
    "candidates",
    "registered",
    "accepted",
    "rejected",
    "true_candidates",
    "distant_loops",
    "revisits",
    "revisits_closed",
    "revisit_recall",
    "revisit_keyframes",
    "revisit_keyframes_closed",
    "revisit_keyframe_recall",
)


def _memory_json(memory: Memory) -> dict[str, JSONValue]:
    a = memory.accounted
    out: dict[str, JSONValue] = {
        "keyframe_descriptors": a.keyframe_descriptors,
        "keyframe_clouds": a.keyframe_clouds,
        "graph": a.graph,
        **({} if a.local_map is None else {"local_map": a.local_map}),
        "total": a.total,
        "run_records": a.run_records,
        "map": a.map,
        "in_ram": a.in_ram,
    }
    if a.cloud_store is not None:
        out.update(keyframe_clouds_on_disk=a.clouds_on_disk, cloud_store=a.cloud_store)
    return out


def _batch_tail(m: RunMetrics) -> dict[str, JSONValue]:
    t, s, pr = m.timing, m.setup, m.place_recognition
    ref = pr.reference
    if t.frontend_s is None or t.frontend_cached is None:
        raise ValueError(f"{m.run.sequence}: a batch run's report lacks its front end's timing")
    return {
        "sampler_realtime_fraction": _none(t.sampler_realtime_fraction),
        "time_s": dict(t.stages),
        "frontend_time_s": dict(t.frontend_s),
        "frontend_cached": dict(t.frontend_cached),
        "replayed_time_s": dict(t.replayed_s),
        "odometry_config": s.odometry_config,
        "deskew": s.deskew.on,
        "deskew_from": s.deskew.why,
        "threads": dict(s.threads),
        "pr_reference": _fields(ref, ("pr_auc", "f1_max", "matches")),
        "threshold_sweep": None if isinstance(pr.sweep, Unavailable) else [_fields(row, SWEEP_ROW) for row in pr.sweep],
    }


def _online_tail(m: RunMetrics) -> dict[str, JSONValue]:
    th, s = m.throughput, m.setup
    if th is None:
        raise ValueError(f"{m.run.sequence}: an online run's report lacks its throughput")
    return {
        "bytes_per_keyframe": m.memory.bytes_per_keyframe(m.run.keyframes),
        "time_s": dict(m.timing.stages),
        "pipeline_time_s": th.pipeline_time_s,
        "fps": th.fps,
        "backend_fps": th.backend_fps,
        "frame_rate_hz": th.frame_rate_hz,
        "frame_rate_from": th.frame_rate_from,
        "realtime_factor": th.realtime_factor,
        "latency_ms": {step: _fields(p, ("p50", "p95", "p99", "max")) for step, p in th.latency_ms.items()},
        "odometry_cached": th.odometry_cached,
        "replayed_time_s": dict(m.timing.replayed_s),
        "threads": dict(s.threads),
        "deskew": s.deskew.on,
        "deskew_from": s.deskew.why,
    }


def to_json(m: RunMetrics) -> dict[str, JSONValue]:
    """The report as metrics.json holds it (key order included); with its stamp when it has one."""
    run, loops, kt, full, pr, memory = m.run, m.loops, m.keyframe_trajectory, m.full_rate, m.place_recognition, m.memory
    out: dict[str, JSONValue] = {"pipeline": ONLINE} if m.online else {}
    out.update(
        {
            **_fields(run, ("sequence", "dataset", "method", "sampler", "descriptor", "mode", "frames", "keyframes")),
            "candidates": loops.candidates,
            "true_candidates": _none(loops.true_candidates),
            "verified": loops.verified,
            "registrations": loops.registrations,
            "false_loops": _none(loops.false_loops),
            "loop_closing": {"rejected": dict(loops.closing.rejected), **loops.closing.details},
            "loop_accounting": {**_fields(loops.accounting, ACCOUNTING), "rejected": dict(loops.accounting.rejected)},
            "before": _fields(kt.before, KEYFRAME_ERRORS),
            "after": _fields(kt.after, KEYFRAME_ERRORS),
            "improvement_pct": _fields(kt.improvement, IMPROVEMENT),
            "ate_alignment": _none(kt.alignment),
            "ate_rotation_reliable": _none(kt.rotation_reliable),
            "unavailable": dict(m.reasons),
            "full_rate": {
                "before": _fields(full.before, FULL_RATE_ERRORS),
                "after": _fields(full.after, FULL_RATE_ERRORS),
                "improvement_pct": _fields(full.improvement, IMPROVEMENT),
                "frames": full.frames,
                "ate_alignment": _none(full.alignment),
            },
            "warnings": list(m.warnings),
            "pr_auc": _none(pr.pr_auc),
            "f1_max": _none(pr.f1_max),
            "pr_queries": pr.queries,
            "memory_bytes": _memory_json(memory),
            "peak_rss_bytes": memory.peak_rss_bytes,
            "peak_rss_scope": memory.peak_rss_scope,
            "rss_growth_bytes": memory.rss_growth_bytes,
            "rss_growth_ratio": _none(memory.rss_growth_ratio),
            "sampler_stats": dict(m.sampler_stats),
        }
    )
    out.update(_online_tail(m) if m.online else _batch_tail(m))
    if m.stamp is not None:
        out.update(msa_slam_version=m.stamp.version, keyframe_frames=list(m.stamp.keyframe_frames))
    return out
