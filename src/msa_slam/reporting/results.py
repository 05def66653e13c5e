"""Result folder of one run, batch or online: config.yaml, metrics.json (keys explained in docs/metrics.md),
frames.csv, loops.csv, pr.csv, trajectories (KITTI + TUM, the frames' own timestamps: full-rate ground truth
and odometry, keyframe trajectories), map.ply (keyframe clouds at their optimised poses), pose_graph.g2o,
descriptors.npy (batch: every frame's descriptor, for `msa-slam sample`), provenance.json, figures and
report.md; an online run adds steps.csv (per frame: step times, memory) and its memory and step-time figures.
The folder is built under a temporary name and moved into place when complete (msa_slam.io.outputs)."""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

import msa_slam
from msa_slam.evaluation import NA, AlignmentError, align_se3, fmt
from msa_slam.evaluation.loops import is_false_loop
from msa_slam.evaluation.metrics import known
from msa_slam.evaluation.metrics_writer import to_json
from msa_slam.evaluation.run_metrics import Stamp
from msa_slam.io.g2o import format_g2o
from msa_slam.io.outputs import DEFAULT_RESULTS, open_result_folder
from msa_slam.io.ply import write_ply
from msa_slam.io.poses import write_poses
from msa_slam.io.provenance import provenance
from msa_slam.io.tables import rows_csv, write_json
from msa_slam.place_recognition.figures import plot_pr_curves
from msa_slam.reporting.report import report_markdown
from msa_slam.reporting.sequence_text import sequence_title
from msa_slam.slam import RunResult
from msa_slam.viz import TrajectoryPanel, plot_memory, plot_step_times, plot_trajectories
from msa_slam.viz.labels import counted, sampler_label


def frames_csv(result: RunResult) -> str:
    """One row per frame: time, keyframe flag, odometry / GT / optimised positions, ATE of keyframes."""
    row_of = {int(k): i for i, k in enumerate(result.keyframes)}
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(
        [
            "frame",
            "time",
            "is_keyframe",
            "odom_x",
            "odom_y",
            "odom_z",
            "gt_x",
            "gt_y",
            "gt_z",
            "opt_x",
            "opt_y",
            "opt_z",
            "ate_odom_m",
            "ate_opt_m",
        ]
    )
    for i in range(len(result)):
        row = [i, f"{result.times[i]:.6f}", int(i in row_of)]
        row += [f"{v:.6f}" for v in result.odometry[i, :3, 3]]
        row += [""] * 3 if result.gt_poses is None else [f"{v:.6f}" for v in result.gt_poses[i, :3, 3]]
        k = row_of.get(i)
        if k is None:
            row += [""] * 5
        else:
            row += [f"{v:.6f}" for v in result.optimised[k, :3, 3]]
            row += [
                NA if (errors := result.ate_errors[e]) is None else f"{errors[k]:.6f}"
                for e in ("odometry", "optimised")
            ]
        writer.writerow(row)
    return buf.getvalue()


def loops_csv(result: RunResult) -> str:
    """One row per loop candidate: match, similarity, GT distance, registration outcome, false-loop flag (an
    accepted loop whose measured pose is off ground truth, evaluation.loops.is_false_loop; n/a without ground
    truth)."""
    radius, gt = result.config.loop_radius, result.gt_poses if has_ground_truth(result) else None
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(
        [
            "query_frame",
            "match_frame",
            "similarity",
            "gt_distance_m",
            "registered",
            "accepted",
            "residual_m",
            "false_loop",
        ]
    )
    for c in result.loops:
        known = bool(np.isfinite(c.gt_distance))  # NaN without ground truth
        false = NA if gt is None else int(c.accepted and is_false_loop(c, gt, radius))
        writer.writerow(
            [
                c.query,
                c.match,
                f"{c.similarity:.6f}",
                f"{c.gt_distance:.4f}" if known else NA,
                int(c.verified),
                int(c.accepted),
                f"{c.residual:.4f}",
                false,
            ]
        )
    return buf.getvalue()


def steps_csv(result: RunResult) -> str:
    """Online runs: per frame, each step's time (ms), the back-end's total and the memory series."""
    steps, memory = list(result.steps_ms), list(result.memory)
    backend = result.backend_ms
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["frame", *(f"{s}_ms" for s in steps), "backend_ms", *memory])
    for i in range(len(result)):
        writer.writerow(
            [
                i,
                *(f"{result.steps_ms[s][i]:.3f}" for s in steps),
                f"{backend[i]:.3f}",
                *(int(result.memory[m][i]) for m in memory),
            ]
        )
    return buf.getvalue()


def write_trajectory_files(folder: Path, result: RunResult) -> None:
    """Keyframe trajectories (optimised, odometry, GT) and the full-rate optimised (every frame from its
    preceding keyframe's optimised pose and the odometry since), odometry and GT, in KITTI and TUM."""
    folder.mkdir()
    kf, times = result.keyframes, np.asarray(result.times, dtype=np.float64)
    trajectories = [
        ("optimised", result.optimised_full, times),
        ("optimised_keyframes", result.optimised, times[kf]),
        ("odometry_keyframes", result.odometry[kf], times[kf]),
        ("odometry", result.odometry, times),
    ]
    gt = result.gt_poses
    if gt is not None and has_ground_truth(result):
        trajectories += [("gt_keyframes", gt[kf], times[kf]), ("gt", gt, times)]
    for name, poses, stamps in trajectories:
        write_poses(folder / f"{name}.kitti", poses, "kitti")
        write_poses(folder / f"{name}.tum", poses, "tum", stamps)


def has_ground_truth(result: RunResult) -> bool:
    """Whether every frame has a ground-truth pose (runs without ground truth carry None or NaN poses)."""
    return result.gt_poses is not None and bool(np.isfinite(result.gt_poses).all())


def pose_graph_g2o(result: RunResult) -> str:
    """The run's pose graph in g2o: keyframes at their optimised poses, every odometry and loop factor with
    the information the optimiser used."""
    return format_g2o(result.keyframes, result.optimised, result.graph_factors)


def pr_csv(result: RunResult) -> str:
    """The PR curve's arrays: one row per similarity threshold (precision, recall, F1)."""
    pr = result.pr
    if pr is None:
        raise ValueError(f"{result.name}: the run has no PR curve to write")
    rows = [
        {"threshold": f"{t:.2f}", "precision": f"{p:.6f}", "recall": f"{r:.6f}", "f1": f"{f:.6f}"}
        for t, p, r, f in zip(pr.thresholds, pr.precision, pr.recall, pr.f1)
    ]
    return rows_csv(rows, ("threshold", "precision", "recall", "f1"))


def loop_edges(result: RunResult) -> tuple[list, list]:
    """Accepted loops as (match row, query row) pairs into the keyframe list: true ones, then false ones (measured
    pose off ground truth, evaluation.loops.is_false_loop; none without ground truth)."""
    row = {int(k): i for i, k in enumerate(result.keyframes)}
    gt = result.gt_poses if has_ground_truth(result) else None
    good: list[tuple[int, int]] = []
    bad: list[tuple[int, int]] = []
    for c in result.accepted_loops:
        false = gt is not None and is_false_loop(c, gt, result.config.loop_radius)
        (bad if false else good).append((row[c.match], row[c.query]))
    return good, bad


def trajectory_panel(
    name: str,
    ate_m: float | None,
    estimate: np.ndarray,
    gt: np.ndarray | None,
    errors: np.ndarray | None,
    loops: tuple[list, list] | None = None,
) -> TrajectoryPanel:
    """A keyframe trajectory SE(3)-aligned to `gt` and coloured by its ATE; drawn as estimated, in one colour,
    without ground truth or when the alignment is undetermined. `loops` (true, false) are drawn on it; None:
    none belong to it."""
    if gt is None:
        xy, title = estimate[:, :2, 3], f"{name} (no ground truth: no ATE)"
    else:
        try:
            xy = align_se3(estimate, gt)[:, :2, 3]
            title = f"{name}, keyframe ATE {fmt(ate_m, '.3f', ' m')}"
        except AlignmentError:
            xy, title, errors = estimate[:, :2, 3], f"{name} (not aligned), keyframe ATE n/a", None
    return TrajectoryPanel(title, xy, errors) if loops is None else TrajectoryPanel(title, xy, errors, *loops)


def trajectory_panels(result: RunResult) -> tuple[TrajectoryPanel, TrajectoryPanel]:
    """Odometry and optimised keyframe trajectories (SE(3)-aligned to GT); the loops on the optimised one (the
    odometry knows none, and compare draws one odometry panel beside every method's)."""
    kf, m = result.keyframes, result.measured
    gt, loops = None if result.gt_poses is None else result.gt_poses[kf], loop_edges(result)
    optimiser = "iSAM2" if m.online else "optimised"
    ate = m.keyframe_trajectory
    return (
        trajectory_panel(
            "odometry", known(ate.before.ate_translation_m), result.odometry[kf], gt, result.ate_errors["odometry"]
        ),
        trajectory_panel(
            f"{m.method} {optimiser}",
            known(ate.after.ate_translation_m),
            result.optimised,
            gt,
            result.ate_errors["optimised"],
            loops,
        ),
    )


def reference_xy(result: RunResult) -> np.ndarray:
    """The ground-truth path drawn behind trajectory panels (none without ground truth)."""
    return np.empty((0, 2)) if result.gt_poses is None else result.gt_poses[:, :2, 3]


def accounted_bytes(memory: dict[str, np.ndarray]) -> np.ndarray:
    """Per-frame accounted memory: keyframe clouds (RAM and disk), descriptors and graph."""
    return memory["cloud_bytes"] + memory["cloud_disk_bytes"] + memory["descriptor_bytes"] + memory["graph_bytes"]


RUN_FIGURES = ("trajectories.png", "memory.png", "step_times.png", "pr_curve.png")  # report.md's order


def run_figures(folder: Path) -> list[str]:
    """The figures of RUN_FIGURES in `folder`, in report.md's order (which ones depends on what the run made)."""
    return [name for name in RUN_FIGURES if (folder / name).is_file()]


def folder_files(folder: Path) -> set[str]:
    """Relative POSIX paths of everything in a result folder: what its report.md may list and name."""
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*")}


def _write_figures(result: RunResult, folder: Path) -> list[str]:
    folder.mkdir()
    m, cfg = result.measured, result.config
    online = " online" if m.online else ""
    sequence = sequence_title(m.run.sequence, cfg.source, len(result))
    # a labelled run (compare's "constant-2m") says its parameters in its label
    method = m.method if cfg.label else sampler_label(cfg.sampler, cfg.sampler_params)
    plot_trajectories(
        folder / "trajectories.png",
        reference_xy(result),
        trajectory_panels(result),
        title=f"{sequence}: {method}{online} ({counted(m.run.keyframes, 'keyframe')}, "
        f"{counted(m.loops.verified, 'loop')}, "
        f"{m.run.mode} mode)",
    )
    if result.memory:
        plot_memory(
            folder / "memory.png",
            {m.method: (np.arange(len(result)), accounted_bytes(result.memory), result.memory["rss_bytes"])},
            title=f"{sequence}: memory over time",
        )
        new_kf = np.diff(result.memory["keyframes"], prepend=0) > 0
        plot_step_times(
            folder / "step_times.png",
            {
                "graph update (iSAM2)": {m.method: result.steps_ms["graph_update"][new_kf]},
                "loop detection": {m.method: result.steps_ms["loop_detection"][new_kf]},
                "back-end per frame": {m.method: result.backend_ms},
            },
            title=f"{sequence}: per-step time",
        )
    if result.pr is not None and result.pr.auc is not None:
        plot_pr_curves({m.method: result.pr}, folder / "pr_curve.png", title=f"{sequence}: loop candidates")
    return run_figures(folder)


def write_run_files(result: RunResult, folder: Path, figures: bool = True) -> None:
    """Write all outputs of `result` into an existing (temporary) folder."""
    (folder / "config.yaml").write_text(yaml.safe_dump(result.config.dump(), sort_keys=False))
    stamp = Stamp(msa_slam.__version__, tuple(int(k) for k in result.keyframes))
    write_json(folder / "metrics.json", to_json(replace(result.measured, stamp=stamp)))
    write_json(folder / "provenance.json", provenance())
    (folder / "frames.csv").write_text(frames_csv(result))
    (folder / "loops.csv").write_text(loops_csv(result))
    if result.pr is not None:
        (folder / "pr.csv").write_text(pr_csv(result))
    if result.memory:
        (folder / "steps.csv").write_text(steps_csv(result))
    write_trajectory_files(folder / "trajectories", result)
    (folder / "pose_graph.g2o").write_text(pose_graph_g2o(result))
    if result.map_points is not None:
        write_ply(folder / "map.ply", result.map_points)
    if result.descriptors is not None:
        np.save(folder / "descriptors.npy", result.descriptors)
    names = _write_figures(result, folder / "figures") if figures else []
    (folder / "report.md").write_text(report_markdown(result, names, folder_files(folder)))


def write_run(
    make: Callable[[], RunResult], out: str | os.PathLike | None, command: str = "run", overwrite: bool = False
) -> Path:
    """The result folder `out` of the run `make` returns, written atomically; `out` is checked before `make` does
    any work (as `open_result_folder` does; None: a new timestamped folder under msa_slam_results/<command>, run
    or online); return the path of its report.md."""
    with open_result_folder(out, command, DEFAULT_RESULTS / command, overwrite=overwrite) as folder:
        result = make()
        with folder.staging() as tmp:
            write_run_files(result, tmp)
    return folder.path / "report.md"
