"""metrics.json -> RunMetrics: `from_json` reads a stored metrics.json (or a comparison.json entry) back, refusing a
missing key or a wrong type by name, for `msa-slam report`, compare's reuse of finished seeds and experiment cells.
Its inverse, evaluation.metrics_writer.to_json, writes the keys this reads, so a round trip gives the same bytes.
"""

from __future__ import annotations

from typing import Any

from msa_slam.evaluation.metrics import (
    NOT_BATCH,
    NOTHING_IN_RAM,
    ONLINE,
    AccountedMemory,
    Deskew,
    FullRateErrors,
    FullRateTrajectory,
    Improvement,
    KeyframeErrors,
    KeyframeTrajectory,
    Latency,
    LoopClosing,
    LoopCounts,
    Loops,
    Memory,
    PlaceRecognition,
    ReferencePR,
    RunIdentity,
    RunSetup,
    SweepRow,
    Throughput,
    Timing,
    Unavailable,
    Value,
)
from msa_slam.evaluation.metrics_reader import MetricsDocument
from msa_slam.evaluation.run_metrics import RunMetrics, Stamp

_FULL_RATE = ("full_rate_ate_optimised", "full_rate_ate")
LOOP_TRUTH = ("true_candidates", "distant_loops", "revisits", "revisits_closed")
DISTANCE_FALSE_LOOPS = (
    "is from an msa-slam that counted loops as false by their keyframes' ground-truth distance; false_loops "
    "now counts accepted loops whose measured pose is off ground truth: rerun to get it"
)
REVISIT_KEYFRAMES = ("revisit_keyframes", "revisit_keyframes_closed")


def _keyframe_errors(doc: MetricsDocument, ate_keys: tuple[str, ...]) -> KeyframeErrors:
    return KeyframeErrors(
        doc.value("ate_translation_m", *ate_keys),
        doc.value("ate_rotation_deg", *ate_keys),
        doc.value("rpe_translation_m", "rpe", "ate"),
        doc.value("rpe_rotation_deg", "rpe", "ate"),
    )


def _full_rate_errors(doc: MetricsDocument, ate_keys: tuple[str, ...]) -> FullRateErrors:
    kitti, ten = ("rpe_kitti", *ate_keys), ("rpe_10m", *ate_keys)
    return FullRateErrors(
        doc.value("ate_translation_m", *ate_keys),
        doc.value("ate_rotation_deg", *ate_keys),
        doc.value("rpe_kitti_translation_pct", *kitti),
        doc.value("rpe_kitti_rotation_deg_per_100m", *kitti),
        doc.value("rpe_10m_translation_m", *ten),
        doc.value("rpe_10m_rotation_deg", *ten),
    )


def _improvement(doc: MetricsDocument, prefix: str, ate_keys: tuple[str, ...]) -> Improvement:
    return Improvement(
        doc.value("translation", f"{prefix}improvement_translation", *ate_keys),
        doc.value("rotation", f"{prefix}improvement_rotation", *ate_keys),
    )


def _text(doc: MetricsDocument, key: str, *reason_keys: str) -> str | Unavailable:
    text = doc.typed(key, str, nullable=True)
    return text if text is not None else doc.unavailable(*reason_keys)


def read_keyframe_trajectory(doc: MetricsDocument) -> KeyframeTrajectory:
    reliable = doc.typed("ate_rotation_reliable", bool, nullable=True)
    return KeyframeTrajectory(
        _keyframe_errors(doc.sub("before"), ("ate_odometry", "ate")),
        _keyframe_errors(doc.sub("after"), ("ate_optimised", "ate")),
        _improvement(doc.sub("improvement_pct"), "", ("ate_optimised", "ate", "ate_odometry")),
        _text(doc, "ate_alignment", "ate"),
        doc.unavailable("ate") if reliable is None else reliable,
    )


def read_full_rate(doc: MetricsDocument) -> FullRateTrajectory:
    return FullRateTrajectory(
        _full_rate_errors(doc.sub("before"), ("full_rate_ate",)),
        _full_rate_errors(doc.sub("after"), _FULL_RATE),
        _improvement(doc.sub("improvement_pct"), "full_rate_", _FULL_RATE),
        doc.typed("frames", int),
        _text(doc, "ate_alignment", "full_rate_ate"),
    )


def _loops(doc: MetricsDocument) -> Loops:
    closing = doc.sub("loop_closing")
    rejected = closing.mapping("rejected", int)
    details = {k: v for k, v in closing.data.items() if k != "rejected"}
    return Loops(
        doc.typed("candidates", int),
        doc.value("true_candidates", "loop_truth", kind=int),
        doc.typed("verified", int),
        doc.typed("registrations", int),
        LoopClosing(rejected, details),
        read_loop_counts(doc.sub("loop_accounting"), doc.value("false_loops", "loop_truth", kind=int)),
    )


def read_loop_counts(acc: MetricsDocument, false_loops: Value) -> LoopCounts:
    """metrics.json `loop_accounting` (evaluation.loops.account_loops) with the top-level `false_loops`; one written
    when false_loops meant keyframes far apart (its accounting had `false_accepted`) is refused."""
    if acc.has("false_accepted"):
        raise acc.error("loop_accounting.false_accepted", DISTANCE_FALSE_LOOPS)
    true_candidates, distant, revisits, closed = (acc.value(k, "loop_truth", kind=int) for k in LOOP_TRUTH)
    keyframes, keyframes_closed = (acc.value(k, "loop_truth", kind=int) for k in REVISIT_KEYFRAMES)
    return LoopCounts(
        acc.typed("candidates", int),
        acc.typed("registered", int),
        acc.typed("accepted", int),
        acc.mapping("rejected", int),
        true_candidates,
        false_loops,
        distant,
        revisits,
        closed,
        acc.value("revisit_recall", "revisit_recall", "loop_truth"),
        keyframes,
        keyframes_closed,
        acc.value("revisit_keyframe_recall", "revisit_recall", "loop_truth"),
    )


def _place_recognition(doc: MetricsDocument) -> PlaceRecognition:
    online = doc.has("pipeline")
    reference: ReferencePR | Unavailable = Unavailable(NOT_BATCH)
    sweep: tuple[SweepRow, ...] | Unavailable = Unavailable(NOT_BATCH)
    if not online:
        ref = doc.sub("pr_reference")
        reference = ReferencePR(
            ref.value("pr_auc", "pr_reference"), ref.value("f1_max", "pr_reference"), ref.typed("matches", int)
        )
        rows = doc.typed("threshold_sweep", list, nullable=True)
        sweep = (
            doc.unavailable("threshold_sweep")
            if rows is None
            else tuple(
                _sweep_row(MetricsDocument(row, doc.source, f"threshold_sweep[{i}]", doc.reasons))
                for i, row in enumerate(rows)
            )
        )
    return PlaceRecognition(
        doc.value("pr_auc", "pr"), doc.value("f1_max", "pr"), doc.typed("pr_queries", int), reference, sweep
    )


def _sweep_row(doc: MetricsDocument) -> SweepRow:
    return SweepRow(
        doc.typed("threshold", float),
        doc.typed("candidates", int),
        doc.typed("loops_accepted", int),
        doc.typed("false_loops", int),
        doc.value("ate_after_m", *_FULL_RATE),
        doc.value("improvement_t_pct", "full_rate_improvement_translation", *_FULL_RATE),
    )


def _memory(doc: MetricsDocument) -> Memory:
    mem = doc.sub("memory_bytes")
    optional = {
        key: mem.typed(key, kind) if mem.has(key) else None
        for key, kind in (("local_map", int), ("keyframe_clouds_on_disk", int), ("cloud_store", str))
    }
    accounted = AccountedMemory(
        mem.typed("keyframe_descriptors", int),
        mem.typed("keyframe_clouds", int),
        mem.typed("graph", int),
        optional["local_map"],
        mem.typed("total", int),
        mem.typed("run_records", int),
        mem.typed("map", int),
        mem.typed("in_ram", int),
        optional["keyframe_clouds_on_disk"],
        optional["cloud_store"],
    )
    return Memory(
        accounted,
        doc.typed("peak_rss_bytes", int),
        doc.typed("peak_rss_scope", str),
        doc.typed("rss_growth_bytes", int),
        doc.value("rss_growth_ratio", default=NOTHING_IN_RAM),
    )


def _throughput(doc: MetricsDocument) -> Throughput:
    latency = doc.sub("latency_ms")
    steps = {
        step: Latency(*(latency.sub(step).typed(p, float) for p in ("p50", "p95", "p99", "max")))
        for step in latency.data
    }
    doc.typed("bytes_per_keyframe", float)  # written from memory_bytes.total and keyframes (to_json)
    return Throughput(
        doc.typed("pipeline_time_s", float),
        doc.typed("fps", float),
        doc.typed("backend_fps", float),
        doc.typed("frame_rate_hz", float),
        doc.typed("frame_rate_from", str),
        doc.typed("realtime_factor", float),
        steps,
        doc.typed("odometry_cached", bool),
    )


def _timing(doc: MetricsDocument, online: bool) -> Timing:
    stages = doc.mapping("time_s", float, nullable=True)
    replayed = doc.mapping("replayed_time_s", float)
    if online:
        return Timing(stages, replayed)
    return Timing(
        stages,
        replayed,
        doc.mapping("frontend_time_s", float),
        doc.mapping("frontend_cached", bool),
        doc.value("sampler_realtime_fraction", "sampler_realtime_fraction"),
    )


def _setup(doc: MetricsDocument, online: bool) -> RunSetup:
    deskew = Deskew(doc.typed("deskew", bool, nullable=True), doc.typed("deskew_from", str))
    threads = doc.mapping("threads", int, nullable=True)
    return RunSetup(deskew, threads, None if online else doc.mapping("odometry_config"))


def from_json(data: Any, source: str) -> RunMetrics:
    """The report in a metrics.json object (`source`: the file, for errors), every key checked first."""
    doc = MetricsDocument(data, source)
    doc.reasons = doc.mapping("unavailable", str)
    online = doc.has("pipeline")
    pipeline = doc.typed("pipeline", str) if online else "batch"
    if online and pipeline != ONLINE:
        raise doc.error("pipeline", f"must be {ONLINE!r} when present, not {pipeline!r}")
    sequence, dataset, method, sampler, descriptor, mode = (
        doc.typed(k, str) for k in ("sequence", "dataset", "method", "sampler", "descriptor", "mode")
    )
    run = RunIdentity(
        sequence, dataset, method, sampler, descriptor, mode, doc.typed("frames", int), doc.typed("keyframes", int)
    )
    stamp = None
    if doc.has("msa_slam_version"):
        frames = doc.typed("keyframe_frames", list)
        if not all(isinstance(f, int) and not isinstance(f, bool) for f in frames):
            raise doc.error("keyframe_frames", "must be a list of integers")
        stamp = Stamp(doc.typed("msa_slam_version", str), tuple(frames))
    warnings = doc.typed("warnings", list)
    if not all(isinstance(w, str) for w in warnings):
        raise doc.error("warnings", "must be a list of strings")
    return RunMetrics(
        pipeline,
        run,
        _loops(doc),
        read_keyframe_trajectory(doc),
        read_full_rate(doc.sub("full_rate")),
        doc.reasons,
        tuple(warnings),
        _place_recognition(doc),
        _memory(doc),
        doc.mapping("sampler_stats"),
        _timing(doc, online),
        _setup(doc, online),
        _throughput(doc) if online else None,
        stamp,
    )
