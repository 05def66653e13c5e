"""Result folder of one run: config.yaml, metrics.json, frames.csv, loops.csv, trajectories (KITTI + TUM),
figures and report.md. The folder is built under a temporary name and moved into place when complete
(msa_slam.io.outputs)."""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

import msa_slam
from msa_slam.evaluation import NA, PROCESS_RSS_LABEL, AlignmentError, align_se3, fmt, notes
from msa_slam.io.outputs import DEFAULT_RESULTS, open_result_folder
from msa_slam.io.poses import write_poses
from msa_slam.pipeline.batch import BatchResult
from msa_slam.place_recognition.figures import plot_pr_curves
from msa_slam.viz import TrajectoryPanel, plot_trajectories

def _json_default(value: Any) -> Any:
    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def write_json(path: Path, data: Any) -> None:
    path.write_text(json.dumps(data, indent=1, default=_json_default) + "\n")


def _frames_csv(result: BatchResult) -> str:
    fe = result.frontend
    row_of = {int(k): i for i, k in enumerate(result.keyframes)}
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["frame", "time", "is_keyframe", "odom_x", "odom_y", "odom_z", "gt_x", "gt_y", "gt_z",
                     "opt_x", "opt_y", "opt_z", "ate_odom_m", "ate_opt_m"])
    for i in range(len(fe)):
        row = [i, f"{fe.sequence.times[i]:.6f}", int(i in row_of)]
        row += [f"{v:.6f}" for v in fe.odometry[i, :3, 3]] + [f"{v:.6f}" for v in fe.gt_poses[i, :3, 3]]
        k = row_of.get(i)
        if k is None:
            row += [""] * 5
        else:
            row += [f"{v:.6f}" for v in result.optimised[k, :3, 3]]
            row += [NA if result.ate_errors[e] is None else f"{result.ate_errors[e][k]:.6f}"
                    for e in ("odometry", "optimised")]
        writer.writerow(row)
    return buf.getvalue()


def loops_csv(loops, loop_radius: float) -> str:
    """One row per loop candidate: match, similarity, GT distance, registration outcome, false-loop flag."""
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["query_frame", "match_frame", "similarity", "gt_distance_m", "registered", "accepted",
                     "residual_m", "false_loop"])
    for c in loops:
        writer.writerow([c.query, c.match, f"{c.similarity:.6f}", f"{c.gt_distance:.4f}", int(c.verified),
                         int(c.accepted), f"{c.residual:.4f}", int(c.accepted and c.gt_distance > loop_radius)])
    return buf.getvalue()


def write_trajectory_files(folder: Path, keyframes: np.ndarray, optimised: np.ndarray, odometry: np.ndarray,
                           gt_poses: np.ndarray, times: np.ndarray) -> None:
    """Optimised, odometry and GT keyframe trajectories plus the full odometry, in KITTI and TUM formats."""
    folder.mkdir()
    times = np.asarray(times, dtype=np.float64)
    for name, poses, stamps in (("optimised_keyframes", optimised, times[keyframes]),
                                ("odometry_keyframes", odometry[keyframes], times[keyframes]),
                                ("gt_keyframes", gt_poses[keyframes], times[keyframes]),
                                ("odometry", odometry, times)):
        write_poses(folder / f"{name}.kitti", poses, "kitti")
        write_poses(folder / f"{name}.tum", poses, "tum", stamps)


def loop_edges(keyframes: np.ndarray, accepted_loops, loop_radius: float) -> tuple[list, list]:
    """Accepted loops as (match row, query row) pairs into the keyframe list: true ones, then false ones."""
    row = {int(k): i for i, k in enumerate(keyframes)}
    good = [(row[c.match], row[c.query]) for c in accepted_loops if c.gt_distance <= loop_radius]
    bad = [(row[c.match], row[c.query]) for c in accepted_loops if c.gt_distance > loop_radius]
    return good, bad


def rows_csv(rows, columns) -> str:
    """A table of dict rows as CSV with the given column order."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns)
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def trajectory_panel(name: str, ate_m: float | None, estimate: np.ndarray, gt: np.ndarray,
                     errors: np.ndarray | None, loops: tuple[list, list]) -> TrajectoryPanel:
    """A keyframe trajectory SE(3)-aligned to `gt` and coloured by its ATE; drawn as estimated (error 0)
    when the alignment is undetermined."""
    try:
        xy = align_se3(estimate, gt)[:, :2, 3]
    except AlignmentError:
        xy, name = estimate[:, :2, 3], f"{name} (not aligned)"
    shown = np.zeros(len(estimate)) if errors is None else errors
    return TrajectoryPanel(f"{name}, ATE {fmt(ate_m, '.2f', ' m')}", xy, shown, *loops)


def trajectory_panels(result: BatchResult) -> tuple[TrajectoryPanel, TrajectoryPanel]:
    """Odometry and optimised keyframe trajectories (SE(3)-aligned to GT) with their loops."""
    kf, fe = result.keyframes, result.frontend
    gt = fe.gt_poses[kf]
    loops = loop_edges(kf, result.accepted_loops, result.config.loop_radius)
    m = result.metrics
    return (trajectory_panel("odometry", m["before"]["ate_translation_m"], fe.odometry[kf], gt,
                             result.ate_errors["odometry"], loops),
            trajectory_panel(f"{m['method']} optimised", m["after"]["ate_translation_m"], result.optimised, gt,
                             result.ate_errors["optimised"], loops))


def _write_figures(result: BatchResult, folder: Path) -> list[str]:
    folder.mkdir()
    m = result.metrics
    plot_trajectories(folder / "trajectories.png", result.frontend.gt_poses[:, :2, 3], trajectory_panels(result),
                      title=f"{m['sequence']}: {m['method']} ({m['keyframes']} keyframes, {m['verified']} loops, "
                            f"{m['mode']})")
    names = ["trajectories.png"]
    if result.pr is not None and result.pr.auc is not None:
        plot_pr_curves({m["method"]: result.pr}, folder / "pr_curve.png", title=f"{m['sequence']}: loop candidates")
        names.append("pr_curve.png")
    return names


def mib(n: float) -> str:
    """Bytes as a MiB string for reports."""
    return f"{n / 2**20:.2f} MiB"


def notes_markdown(metrics: dict[str, Any]) -> list[str]:
    """report.md lines: why each n/a metric is unavailable, then the warnings (nothing when all is well)."""
    items = notes(metrics)
    return ["Notes:", "", *(f"- {item}" for item in items), ""] if items else []


def _report(result: BatchResult, figures: list[str]) -> str:
    m = result.metrics
    b, a, imp = m["before"], m["after"], m["improvement_pct"]
    pr = f"{fmt(m['pr_auc'])} / {fmt(m['f1_max'])}"
    rot = " (unreliable: see notes)" if m.get("ate_rotation_reliable") is False else ""
    lines = [
        f"# {m['method']} on {m['sequence']} ({m['mode']} loops)", "",
        f"{m['frames']} frames -> {m['keyframes']} keyframes; {m['candidates']} loop candidates "
        f"(similarity >= {result.config.similarity_threshold}), {m['verified']} verified, "
        f"{m['false_loops']} false (ground-truth distance > {result.config.loop_radius} m).", "",
        "| metric | odometry | optimised | improvement |", "|---|---|---|---|",
        f"| ATE translation [m] | {fmt(b['ate_translation_m'])} | {fmt(a['ate_translation_m'])} | "
        f"{fmt(imp['translation'], '.1f', ' %')} |",
        f"| ATE rotation [deg]{rot} | {fmt(b['ate_rotation_deg'])} | {fmt(a['ate_rotation_deg'])} | "
        f"{fmt(imp['rotation'], '.1f', ' %')} |",
        f"| RPE translation [m] (consecutive keyframes) | {fmt(b['rpe_translation_m'])} | "
        f"{fmt(a['rpe_translation_m'])} | |",
        f"| RPE rotation [deg] | {fmt(b['rpe_rotation_deg'])} | {fmt(a['rpe_rotation_deg'])} | |", "",
        f"ATE alignment: {m['ate_alignment']}.", "",
        *notes_markdown(m),
        "| PR-AUC / F1-max | memory (keyframes + graph) | back-end time |", "|---|---|---|",
        f"| {pr} | {mib(m['memory_bytes']['total'])} | {m['time_s']['backend_total']:.2f} s |", "",
        f"{PROCESS_RSS_LABEL}: {mib(m['peak_rss_bytes'])}", "",
        "Stage times [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in {**m['frontend_time_s'], **m['time_s']}.items())
        + ("  (front end from cache)" if all(m["frontend_cached"].values()) else ""), "",
    ]
    lines += [f"![{name}](figures/{name})" for name in figures]
    lines += ["", "Files: config.yaml (re-run with `msa-slam run --config`), metrics.json, frames.csv, loops.csv, "
              "trajectories/ (KITTI and TUM formats).", f"msa-slam {msa_slam.__version__}", ""]
    return "\n".join(lines)


def write_run_files(result: BatchResult, folder: Path) -> None:
    """Write all outputs of `result` into an existing (temporary) folder."""
    (folder / "config.yaml").write_text(yaml.safe_dump(result.config.dump(), sort_keys=False))
    write_json(folder / "metrics.json", {**result.metrics, "msa_slam_version": msa_slam.__version__,
                                         "keyframe_frames": result.keyframes.tolist()})
    (folder / "frames.csv").write_text(_frames_csv(result))
    (folder / "loops.csv").write_text(loops_csv(result.loops, result.config.loop_radius))
    fe = result.frontend
    write_trajectory_files(folder / "trajectories", result.keyframes, result.optimised, fe.odometry, fe.gt_poses,
                           fe.sequence.times)
    figures = _write_figures(result, folder / "figures")
    (folder / "report.md").write_text(_report(result, figures))


def write_run(result: BatchResult, out: str | os.PathLike | None, overwrite: bool = False) -> Path:
    """Write the result folder `out` atomically (checked as `open_result_folder` does; None: a new timestamped
    folder under msa_slam_results/run); return the path of its report.md."""
    with open_result_folder(out, "run", DEFAULT_RESULTS / "run", overwrite=overwrite) as folder:
        with folder.staging() as tmp:
            write_run_files(result, tmp)
    return folder.path / "report.md"
