"""Result folder of one online run (built under a temporary name, renamed when complete):
config.yaml, metrics.json, steps.csv (per frame: step times, memory), loops.csv, trajectories (KITTI + TUM),
figures (trajectories, memory over time, per-step times, PR curve) and report.md.

Reuses the batch pipeline's writers (msa_slam.pipeline.results); folders appear atomically (msa_slam.io.outputs).
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np
import yaml

import msa_slam
from msa_slam.evaluation import PROCESS_RSS_LABEL, fmt
from msa_slam.io.outputs import DEFAULT_RESULTS, open_result_folder
from msa_slam.pipeline.online import MEMORY, STEPS, OnlineResult
from msa_slam.pipeline.online_figures import plot_memory, plot_step_times
from msa_slam.pipeline.results import (loop_edges, loops_csv, mib, notes_markdown, trajectory_panel, write_json,
                                       write_trajectory_files)
from msa_slam.place_recognition.figures import plot_pr_curves
from msa_slam.viz import plot_trajectories


def accounted_bytes(memory: dict[str, np.ndarray]) -> np.ndarray:
    """Per-frame accounted memory: keyframe clouds (RAM and disk), descriptors and graph."""
    return (memory["cloud_bytes"] + memory["cloud_disk_bytes"] + memory["descriptor_bytes"]
            + memory["graph_bytes"])


def steps_csv(result: OnlineResult) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["frame", *(f"{s}_ms" for s in STEPS), "backend_ms", *MEMORY])
    backend = result.backend_ms
    for i in range(len(result.odometry)):
        writer.writerow([i, *(f"{result.steps_ms[s][i]:.3f}" for s in STEPS), f"{backend[i]:.3f}",
                         *(int(result.memory[m][i]) for m in MEMORY)])
    return buf.getvalue()


def _figures(result: OnlineResult, folder: Path) -> list[str]:
    folder.mkdir()
    m, kf = result.metrics, result.keyframes
    gt = result.gt_poses[kf]
    loops = loop_edges(kf, result.accepted_loops, result.config.loop_radius)
    panels = [trajectory_panel("odometry", m["before"]["ate_translation_m"], result.odometry[kf], gt,
                               result.ate_errors["odometry"], loops),
              trajectory_panel(f"{m['method']} iSAM2", m["after"]["ate_translation_m"], result.optimised, gt,
                               result.ate_errors["optimised"], loops)]
    plot_trajectories(folder / "trajectories.png", result.gt_poses[:, :2, 3], panels,
                      title=f"{m['sequence']}: {m['method']} online ({m['keyframes']} keyframes, "
                            f"{m['verified']} loops)")
    frames = np.arange(len(result.odometry))
    plot_memory(folder / "memory.png", {m["method"]: (frames, accounted_bytes(result.memory),
                                                      result.memory["rss_bytes"])},
                title=f"{m['sequence']}: memory over time")
    new_kf = np.diff(result.memory["keyframes"], prepend=0) > 0
    plot_step_times(folder / "step_times.png", {
        "graph update (iSAM2)": {m["method"]: result.steps_ms["graph_update"][new_kf]},
        "loop detection": {m["method"]: result.steps_ms["loop_detection"][new_kf]},
        "back-end per frame": {m["method"]: result.backend_ms},
    }, title=f"{m['sequence']}: per-step time")
    names = ["trajectories.png", "memory.png", "step_times.png"]
    if result.pr is not None and result.pr.auc is not None:
        plot_pr_curves({m["method"]: result.pr}, folder / "pr_curve.png", title=f"{m['sequence']}: loop candidates")
        names.append("pr_curve.png")
    return names


def _report(result: OnlineResult, figures: list[str]) -> str:
    m = result.metrics
    b, a, imp, lat = m["before"], m["after"], m["improvement_pct"], m["latency_ms"]
    rot = " (unreliable: see notes)" if m.get("ate_rotation_reliable") is False else ""
    lines = [
        f"# {m['method']} online on {m['sequence']} ({m['mode']} loops)", "",
        f"{m['frames']} frames -> {m['keyframes']} keyframes; {m['candidates']} loop candidates, {m['verified']} "
        f"verified, {m['false_loops']} false. iSAM2 updated at every frame that finalised keyframes.", "",
        "| metric | odometry | iSAM2 | improvement |", "|---|---|---|---|",
        f"| ATE translation [m] | {fmt(b['ate_translation_m'])} | {fmt(a['ate_translation_m'])} | "
        f"{fmt(imp['translation'], '.1f', ' %')} |",
        f"| ATE rotation [deg]{rot} | {fmt(b['ate_rotation_deg'])} | {fmt(a['ate_rotation_deg'])} | "
        f"{fmt(imp['rotation'], '.1f', ' %')} |", "",
        *([f"ATE alignment: {m['ate_alignment']}.", ""] if "ate_alignment" in m else []),
        *notes_markdown(m),
        "| F1-max | memory (keyframes + graph) | bytes / keyframe | frames/s | back-end frames/s | "
        "real-time factor | back-end p99 [ms] |", "|---|---|---|---|---|---|---|",
        f"| {fmt(m['f1_max'])} | {mib(m['memory_bytes']['total'])} ({m['memory_bytes']['cloud_store']}) | "
        f"{m['bytes_per_keyframe']:.0f} | {m['fps']:.1f} | {m['backend_fps']:.1f} | "
        f"{m['realtime_factor']:.2f} | {lat['backend']['p99']:.1f} |", "",
        f"{PROCESS_RSS_LABEL}: {mib(m['peak_rss_bytes'])}", "",
        "Step totals [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in m["time_s"].items())
        + ("  (odometry replayed from cache)" if m.get("odometry_cached") else ""), "",
    ]
    lines += [f"![{name}](figures/{name})" for name in figures]
    lines += ["", "Files: config.yaml, metrics.json, steps.csv (per frame), loops.csv, trajectories/ (KITTI, TUM).",
              f"msa-slam {msa_slam.__version__}", ""]
    return "\n".join(lines)


def write_online_files(result: OnlineResult, folder: Path, figures: bool = True) -> None:
    """Write all outputs of `result` into an existing (temporary) folder."""
    (folder / "config.yaml").write_text(yaml.safe_dump(result.config.dump(), sort_keys=False))
    write_json(folder / "metrics.json", {**result.metrics, "msa_slam_version": msa_slam.__version__,
                                         "keyframe_frames": result.keyframes.tolist()})
    (folder / "steps.csv").write_text(steps_csv(result))
    (folder / "loops.csv").write_text(loops_csv(result.loops, result.config.loop_radius))
    stamps = np.arange(len(result.odometry)) / result.config.sensor_rate_hz
    write_trajectory_files(folder / "trajectories", result.keyframes, result.optimised, result.odometry,
                           result.gt_poses, stamps)
    names = _figures(result, folder / "figures") if figures else []
    (folder / "report.md").write_text(_report(result, names))


def write_online(result: OnlineResult, out: str | os.PathLike | None, figures: bool = True,
                 overwrite: bool = False) -> Path:
    """Write the result folder `out` atomically (checked as `open_result_folder` does; None: a new timestamped
    folder under msa_slam_results/online); return the path of its report.md."""
    with open_result_folder(out, "online", DEFAULT_RESULTS / "online", overwrite=overwrite) as folder:
        with folder.staging() as tmp:
            write_online_files(result, tmp, figures)
    return folder.path / "report.md"
