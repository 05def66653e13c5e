"""report.md of one run, batch or online: what was run, ATE before/after, notes on n/a metrics and warnings,
memory and time, the figures."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any, Protocol

import numpy as np

import msa_slam
from msa_slam.errors import InputError
from msa_slam.evaluation import NA, PROCESS_RSS_LABEL, fmt, notes
from msa_slam.evaluation.full_rate import RPE_10M_EVO
from msa_slam.evaluation.loops import FALSE_LOOP_ANGLE_DEG
from msa_slam.evaluation.metrics import (
    Deskew,
    FullRateTrajectory,
    JSONValue,
    LoopCounts,
    Memory,
    ReferencePR,
    RunSetup,
    SweepRow,
    Unavailable,
    Value,
    known,
)
from msa_slam.evaluation.run_metrics import RunMetrics
from msa_slam.io.tables import mib
from msa_slam.pipeline.config import NO_TIMESTAMPS, NOT_REPRODUCIBLE
from msa_slam.reporting.sequence_text import rpe_segments, scans_read
from msa_slam.slam.build import slam_sampler_params
from msa_slam.slam.loop_closing import candidate_rule
from msa_slam.viz.labels import counted, display_name, sampler_label


class ReportedRun(Protocol):
    """What report.md is made of: a fresh RunResult, or a finished run read back from its folder
    (reporting.stored), so `msa-slam report` rewrites the same text without running anything again."""

    @property
    def config(self) -> Any: ...  # a RunConfig, or the config.yaml a stored run recorded
    @property
    def measured(self) -> RunMetrics: ...  # the run's report
    @property
    def gt_poses(self) -> np.ndarray | None: ...


def notes_markdown(metrics: RunMetrics) -> list[str]:
    """report.md lines: why each n/a metric is unavailable, then the warnings (nothing when all is well)."""
    items = notes(metrics.reasons, metrics.warnings)
    return ["Notes:", "", *(f"- {item}" for item in items), ""] if items else []


def loop_accounting_text(acc: LoopCounts, loop_radius: float, min_travel_m: float) -> str:
    """One paragraph on what became of the loop candidates (metrics.json `loop_accounting`): rejections by
    reason, distant loops and the revisits closed (n/a without ground truth: the notes say why; the false loops are
    in the report's first paragraph)."""
    rejected = ", ".join(f"{reason} {n}" for reason, n in acc.rejected.items() if n) or "none"
    text = (
        f"Loop accounting: {acc.registered} of {counted(acc.candidates, 'candidate')} registered, "
        f"{acc.accepted} accepted, rejected: {rejected}."
    )
    if isinstance(acc.true_candidates, Unavailable):
        return text + " True candidates, distant loops and revisit recall n/a (no ground truth)."
    text += (
        f" {acc.true_candidates} true candidates (within {loop_radius:g} m in ground truth); "
        f"{acc.distant_loops} accepted loops join keyframes more than {loop_radius:g} m apart in ground truth "
        "(distant: not false when their measured pose is right)."
    )
    apart = f"keyframe pairs within {loop_radius:g} m, >= {min_travel_m:g} m of path apart"
    if not acc.revisits:
        return text + f" No ground-truth revisit ({apart})."
    return text + (
        f" Revisits ({apart}): "
        f"{acc.revisits_closed} of {acc.revisits} closed by an accepted loop (recall "
        f"{fmt(acc.revisit_recall)}); keyframes with a revisit: {acc.revisit_keyframes_closed} of "
        f"{acc.revisit_keyframes} closed (recall {fmt(acc.revisit_keyframe_recall)})."
    )


def false_loops_text(false_loops: Value, loop_radius: float) -> str:
    """The report's count of false loops with its definition (evaluation.loops), or why it is n/a."""
    if isinstance(false_loops, Unavailable):
        return "false loops n/a (no ground truth to check a loop's measured pose against)."
    return (
        f"{false_loops} false (measured pose off ground truth by > {loop_radius:g} m or > "
        f"{FALSE_LOOP_ANGLE_DEG:g} deg)."
    )


def _full_rate_rows(full: FullRateTrajectory, span: str) -> list[str]:
    b, a, imp = full.before, full.after, full.improvement
    rows = (
        ("ATE translation [m], full rate", "ate_translation_m", "translation"),
        ("ATE rotation [deg], full rate", "ate_rotation_deg", "rotation"),
        (f"RPE translation [%], {span}", "rpe_kitti_translation_pct", None),
        (f"RPE rotation [deg/100 m], {span}", "rpe_kitti_rotation_deg_per_100m", None),
        ("RPE translation [m], 10 m, all pairs, mean", "rpe_10m_translation_m", None),
        ("RPE rotation [deg], 10 m, all pairs, mean", "rpe_10m_rotation_deg", None),
    )
    return [
        f"| {label} | {fmt(getattr(b, key))} | {fmt(getattr(a, key))} | "
        f"{fmt(getattr(imp, part), '.1f', ' %') if part else ''} |"
        for label, key, part in rows
    ]


def sweep_lines(sweep: tuple[SweepRow, ...] | Unavailable) -> list[str]:
    """The threshold sweep as a table (nothing when it was not run)."""
    if isinstance(sweep, Unavailable) or not sweep:
        return []
    return [
        "Threshold sensitivity (only loop closing and optimisation re-run on the same keyframes):",
        "",
        "| similarity threshold | candidates | loops accepted | false loops | full-rate t. ATE impr. |",
        "|---|---|---|---|---|",
        *(
            f"| {r.threshold:.2f} | {r.candidates} | {r.loops_accepted} | {r.false_loops} | "
            f"{fmt(r.improvement_t_pct, '.1f', ' %')} |"
            for r in sweep
        ),
        "",
    ]


def _rss_growth(memory: Memory) -> str:
    """RSS growth over this run's back-end beside the accounted bytes it should be explained by."""
    return (
        f"RSS growth over this run's back-end: {mib(memory.rss_growth_bytes)} (accounted in RAM: "
        f"{mib(memory.accounted.in_ram)}, ratio {fmt(memory.rss_growth_ratio, '.2f')})"
    )


def _batch_lines(result: ReportedRun) -> list[str]:
    m = result.measured
    pr, timing = m.place_recognition, m.timing
    frontend_s, cached = timing.frontend_s, timing.frontend_cached
    if frontend_s is None or cached is None:
        raise ValueError(f"{m.run.sequence}: a batch run's report lacks its front end's timing")
    ref = pr.reference
    auc, f1 = (ref.pr_auc, ref.f1_max) if isinstance(ref, ReferencePR) else (ref, ref)
    return [
        "| PR-AUC / F1-max (paper) | PR-AUC / F1-max (reference protocol) | memory (keyframes + graph) | "
        "back-end time |",
        "|---|---|---|---|",
        f"| {fmt(pr.pr_auc)} / {fmt(pr.f1_max)} | {fmt(auc)} / {fmt(f1)} | "
        f"{mib(m.memory.accounted.total)} | {timing.backend_total:.2f} s |",
        "",
        *sweep_lines(pr.sweep),
        f"{PROCESS_RSS_LABEL}: {mib(m.memory.peak_rss_bytes)}; {_rss_growth(m.memory)}",
        "",
        f"Sampler time over the data's duration: {fmt(timing.sampler_realtime_fraction, '.4f')} "
        f"({_number(m.sampler_stats, 'optimisation_ms_total') / 1e3:.2f} s of window optimisation).",
        "",
        "Stage times [s]: "
        + ", ".join(
            f"{k} {v:.2f}" for k, v in {**frontend_s, **timing.stages}.items() if v is not None
        )  # threshold_sweep: None when not run
        + replayed_note(cached),
        "",
    ]


def _number(stats: Mapping[str, JSONValue], key: str) -> float:
    """A sampler statistic report.md shows, which must be a number (sampler_stats is free-form JSON)."""
    value = stats[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"metrics.json sampler_stats.{key}: expected a number, got {value!r}")
    return value


def replayed_note(cached: Mapping[str, bool]) -> str:
    """What a time line adds for the stages (`cached`: stage -> read from the cache) that were replayed: their
    time is the one they took when computed (metrics.json `replayed_time_s`)."""
    stages = [stage for stage, hit in cached.items() if hit]
    if not stages:
        return ""
    pronoun = "it" if len(stages) == 1 else "they"
    return f"  ({', '.join(stages)} replayed from the cache, counted with the time {pronoun} took when computed)"


def deskew_text(deskew: Deskew) -> str:
    """The deskew the odometry did and why (metrics.json `deskew`, `deskew_from`); empty for an odometry other
    than KISS-ICP."""
    if deskew.on is None:
        return ""
    return f"Odometry: deskew {'on' if deskew.on else 'off'} ({deskew.why})."


def _rate_source(frame_rate_from: str) -> str:
    """Where the real-time factor's data rate came from (pipeline.live.frame_rate_hz)."""
    if frame_rate_from == "timestamps":
        return "from its timestamps"
    if frame_rate_from == NO_TIMESTAMPS:
        return "the config's sensor_rate_hz: the frames have no timestamps"
    return "the config's sensor_rate_hz: its timestamps span no time"


def _online_lines(result: ReportedRun) -> list[str]:
    m = result.measured
    th, memory = m.throughput, m.memory
    if th is None:
        raise ValueError(f"{m.run.sequence}: an online run's report lacks its throughput")
    return [
        "| PR-AUC / F1-max | memory (keyframes + graph) | bytes / keyframe | frames/s | back-end frames/s | "
        "real-time factor | back-end p99 [ms] |",
        "|---|---|---|---|---|---|---|",
        f"| {fmt(m.place_recognition.pr_auc)} / {fmt(m.place_recognition.f1_max)} | "
        f"{mib(memory.accounted.total)} ({memory.accounted.cloud_store}) | "
        f"{memory.bytes_per_keyframe(m.run.keyframes):.0f} | {th.fps:.1f} | {th.backend_fps:.1f} | "
        f"{th.realtime_factor:.2f} | {th.latency_ms['backend'].p99:.1f} |",
        "",
        "Frames/s: of the whole pipeline as it ran (reading the frames, odometry, descriptor, back end"
        + (
            ", the odometry replayed from the cache counted with the time it took when computed"
            if th.odometry_cached
            else ""
        )
        + f"); real-time factor: frames/s over the data's "
        f"{th.frame_rate_hz:.1f} frames/s (" + _rate_source(th.frame_rate_from) + ").",
        "",
        f"{PROCESS_RSS_LABEL}: {mib(memory.peak_rss_bytes)}; {_rss_growth(memory)}",
        "",
        "Step totals [s]: "
        + ", ".join(f"{k} {v:.2f}" for k, v in m.timing.stages.items())
        + replayed_note({"odometry": th.odometry_cached}),
        "",
        *([threads_text(m.setup), ""] if threads_text(m.setup) else []),
    ]


def threads_text(setup: RunSetup) -> str:
    """The threads KISS-ICP registered with (metrics.json `threads`), and whether the run is bit-reproducible;
    empty for another odometry."""
    threads = setup.odometry_threads
    if threads is None:
        return ""
    return f"Odometry: KISS-ICP on {counted(threads, 'thread')}" + (
        f", {NOT_REPRODUCIBLE} (see the notes)." if threads > 1 else " (bit-reproducible)."
    )


# What the files of a result folder hold, in the order report.md lists them ({command}: run or online;
# {ground_truth}: "ground truth, " when trajectories/ holds it)
RESULT_FILES = {
    "config.yaml": "config.yaml (re-run with `msa-slam {command} --config`)",
    "metrics.json": "metrics.json (every key explained in docs/metrics.md of msa-slam)",
    "frames.csv": "frames.csv",
    "loops.csv": "loops.csv",
    "pr.csv": "pr.csv",
    "steps.csv": "steps.csv (per-frame step times and memory)",
    "descriptors.npy": "descriptors.npy (every frame's)",
    "trajectories": "trajectories/ (KITTI and TUM with the frames' times: full-rate {ground_truth}odometry and "
    "optimised, keyframe trajectories)",
    "map.ply": "map.ply (keyframe clouds at the optimised poses)",
    "pose_graph.g2o": "pose_graph.g2o",
    "provenance.json": "provenance.json (versions, command line, date, CPU)",
}


def standstill_note(cfg: Any, m: RunMetrics) -> str:
    """The standstill gate the SLAM core ran the sampler with, and the frames it held back (empty when off)."""
    gate = slam_sampler_params(cfg.sampler, cfg.sampler_params)
    motion, rotation = float(gate.get("min_motion", 0.0)), float(gate.get("min_rotation", 0.0))
    if motion <= 0:
        return ""
    turned = f" and turned < {rotation:g} deg" if rotation > 0 else ""
    held = m.sampler_stats.get("standstill_frames")  # counted by samplers with the gate
    if held is not None and (isinstance(held, bool) or not isinstance(held, int)):
        raise InputError(f"metrics.json sampler_stats.standstill_frames: expected an integer, got {held!r}")
    return (
        f" Standstill gate: a frame that moved < {motion:g} m{turned} since the last frame passed on is no "
        f"keyframe candidate" + ("" if held is None else f" ({counted(held, 'frame')} held back)") + "."
    )


RPE_STATISTICS = (
    "The KITTI RPE is the KITTI devkit's mean over the segments; the 10 m RPE is evo's all-pairs "
    "RPE, the mean over every frame paired with the frame nearest 10 m further along the ground-truth "
    "path (within 1 m)."
)
GT_FILE = "trajectories/gt.tum"  # written only for a run with a ground-truth pose for every frame


def alignment_text(m: RunMetrics, files: Collection[str], ground_truth: bool = True) -> str:
    """How the ATE rows were aligned, with the evo commands that reproduce them and the RPE rows only when the run
    wrote the ground-truth trajectories they read (`files`): a report must not send its reader to a missing file.
    `ground_truth`: whether the run had any (without, there is no ATE to align)."""
    if not ground_truth:
        return "ATE alignment: n/a (no ground truth, so no ATE to align and no ground-truth trajectory written)."
    full, keyframes = known(m.full_rate.alignment) or NA, known(m.keyframe_trajectory.alignment) or NA
    if GT_FILE not in files:
        return (
            f"ATE alignment of the full-rate rows: {full}; of the keyframe rows: {keyframes} (no ground-truth "
            "trajectory was written: not every frame has a ground-truth pose)."
        )
    return (
        f"ATE alignment of the full-rate rows: {full} (`evo_ape tum {GT_FILE} trajectories/optimised.tum -a` "
        f"reproduces them); of the keyframe rows: {keyframes} (`evo_ape tum trajectories/gt_keyframes.tum "
        "trajectories/optimised_keyframes.tum -a`). "
        f"`{RPE_10M_EVO.format(reference=GT_FILE, estimate='trajectories/optimised.tum')}` prints the 10 m RPE "
        "as its mean (`--pose_relation angle_deg`: the rotation; `odometry.tum`: the odometry column); `evo_rpe "
        "tum trajectories/gt_keyframes.tum trajectories/optimised_keyframes.tum` the keyframe RPE as its rmse."
    )


def report_markdown(result: ReportedRun, figures: list[str], files: Collection[str]) -> str:
    """The run's report.md text; `figures` are file names under figures/, `files` the relative paths of the
    files and folders in the result folder (only those are listed or named: which files a run writes depends
    on what it produced)."""
    m, cfg, run = result.measured, result.config, result.measured.run
    online = m.online
    kt = m.keyframe_trajectory
    b, a, imp = kt.before, kt.after, kt.improvement
    rot = " (unreliable: see notes)" if kt.rotation_reliable is False else ""
    after = "iSAM2" if online else "optimised"
    rpe_span, rpe_text = rpe_segments(result.gt_poses)
    lines = [
        f"# {run.method}{' online' if online else ''} on {display_name(run.sequence)} ({run.mode} loops)",
        "",
        f"Sampler: {sampler_label(cfg.sampler, cfg.sampler_params)}.{standstill_note(cfg, m)}",
        "",
        f"Dataset `{cfg.dataset}` (sequence {run.sequence}), {scans_read(cfg.source)}: "
        f"{run.frames} frames -> {run.keyframes} keyframes; {counted(m.loops.candidates, 'loop candidate')} "
        f"({candidate_rule(cfg)}), {m.loops.verified} verified, "
        + false_loops_text(m.loops.false_loops, cfg.loop_radius)
        + (" iSAM2 updated at every frame that finalised keyframes." if online else ""),
        "",
        *([deskew_text(m.setup.deskew), ""] if deskew_text(m.setup.deskew) else []),
        loop_accounting_text(m.loops.accounting, cfg.loop_radius, cfg.min_travel_m),
        "",
        f"| metric | odometry | {after} | improvement |",
        "|---|---|---|---|",
        *_full_rate_rows(m.full_rate, rpe_span),
        f"| ATE translation [m], keyframes only | {fmt(b.ate_translation_m)} | {fmt(a.ate_translation_m)} | "
        f"{fmt(imp.translation, '.1f', ' %')} |",
        f"| ATE rotation [deg]{rot}, keyframes only | {fmt(b.ate_rotation_deg)} | {fmt(a.ate_rotation_deg)} | "
        f"{fmt(imp.rotation, '.1f', ' %')} |",
        f"| RPE translation [m], consecutive keyframes, RMSE | {fmt(b.rpe_translation_m)} | "
        f"{fmt(a.rpe_translation_m)} | |",
        f"| RPE rotation [deg], consecutive keyframes, RMSE | {fmt(b.rpe_rotation_deg)} | "
        f"{fmt(a.rpe_rotation_deg)} | |",
        "",
        "Full rate: every frame, its pose from its preceding keyframe's optimised pose and the odometry since "
        '(trajectories/optimised.tum); the same odometry "before" for every sampler. '
        f"{rpe_text}. "
        + (
            RPE_STATISTICS
            if result.gt_poses is not None
            else "RPE over 10 m of travelled path: n/a without ground truth."
        ),
        "",
        alignment_text(m, files, result.gt_poses is not None),
        "",
        *notes_markdown(m),
        *(_online_lines(result) if online else _batch_lines(result)),
    ]
    lines += [f"![{name}](figures/{name})" for name in figures]
    ground_truth = "ground truth, " if GT_FILE in files else ""
    listed = [
        text.format(command="online" if online else "run", ground_truth=ground_truth)
        for name, text in RESULT_FILES.items()
        if name in files
    ]
    lines += ["", f"Files: {', '.join(listed)}.", f"msa-slam {msa_slam.__version__}", ""]
    return "\n".join(lines)
