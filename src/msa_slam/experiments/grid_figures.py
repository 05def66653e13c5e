"""An experiment's figures (figures/ of its report.md): ATE difference to the reference method (box plots), memory
over time and per-step times of the online cells, and metrics against swept parameters (the paper's Fig. 9). Apart
from the tables (experiments.report) because they read the cells' per-step records and draw, the tables do not."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from msa_slam.experiments.folder import FinishedCell, read_steps
from msa_slam.experiments.grid import slug
from msa_slam.experiments.rows import CellRow
from msa_slam.reporting.results import accounted_bytes
from msa_slam.viz import plot_ate_difference, plot_memory, plot_step_times, plot_sweeps

SWEEP_METRICS = {
    "t. ATE impr. [%]": "improvement_t_pct",
    "R. ATE impr. [%]": "improvement_r_pct",
    "F1-max": "f1_max",
    "memory vs reference [%]": "memory_vs_reference_pct",
}


def write_figures(cells: list[FinishedCell], rows: list[CellRow], reference: str, folder: Path) -> list[str]:
    names = []
    folder.mkdir(parents=True, exist_ok=True)
    ref_ate = {
        (r.dataset, r.descriptor, r.parameters, r.seed): r.value("ate_after_m") for r in rows if r.method == reference
    }
    diffs: dict[str, list[float]] = defaultdict(list)
    for r in rows:
        ref, ate = ref_ate.get((r.dataset, r.descriptor, r.parameters, r.seed)), r.value("ate_after_m")
        if ref is not None and ate is not None and r.method != reference:  # else n/a: see notes
            diffs[r.method].append(ate - ref)
    if diffs:
        absent = {
            m: "ATE n/a on every cell: see the notes"
            for m in dict.fromkeys(r.method for r in rows)
            if m != reference and m not in diffs
        }
        plot_ate_difference(
            folder / "ate_difference.png",
            diffs,
            title=f"ATE after optimisation minus {reference}",
            reference=reference,
            absent=absent,
        )
        names.append("ate_difference.png")
    by_dataset: dict[str, list[FinishedCell]] = defaultdict(list)
    for c in cells:
        if c.info.pipeline == "online":
            by_dataset[c.info.dataset].append(c)
    for dataset, group in by_dataset.items():
        first_seed = min(c.info.seed for c in group)
        memory: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        graph: dict[str, list[np.ndarray]] = {}
        loops: dict[str, list[np.ndarray]] = {}
        for c in group:
            steps = read_steps(c.folder)
            if steps is None:
                continue
            label = c.info.method + (f" {c.info.parameters}" if c.info.parameters else "")
            new_kf = np.diff(steps["keyframes"], prepend=0) > 0
            graph.setdefault(label, []).append(steps["graph_update_ms"][new_kf])
            loops.setdefault(label, []).append(steps["loop_detection_ms"][new_kf])
            if c.info.seed == first_seed:
                memory[label] = (steps["frame"], accounted_bytes(steps), steps["rss_bytes"])
        if not memory:
            continue
        tag = slug(dataset)
        plot_memory(folder / f"memory_{tag}.png", memory, title=f"{dataset}: memory over time")
        plot_step_times(
            folder / f"step_times_{tag}.png",
            {
                "incremental PGO (iSAM2) per keyframe step": {k: np.concatenate(v) for k, v in graph.items()},
                "loop closure detection per keyframe step": {k: np.concatenate(v) for k, v in loops.items()},
            },
            title=f"{dataset}: per-step time",
        )
        names += [f"memory_{tag}.png", f"step_times_{tag}.png"]
    sweeps: dict[str, dict[str, dict[str, tuple[list, list]]]] = {}
    swept_rows = [(c.info, r) for c, r in zip(cells, rows) if c.info.swept]
    for key in sorted({k for info, _ in swept_rows for k in info.swept}):
        sweeps[key] = {}
        for title, column in SWEEP_METRICS.items():
            lines: dict[str, dict[float, list[float]]] = defaultdict(lambda: defaultdict(list))
            for info, r in swept_rows:
                if key in info.swept and (x := r.value(column)) is not None:
                    lines[info.dataset][float(info.swept[key])].append(x)
            sweeps[key][title] = {
                ds: (sorted(pts), [float(np.mean(pts[x])) for x in sorted(pts)]) for ds, pts in lines.items()
            }
    if sweeps:
        plot_sweeps(folder / "distance_bounds.png", sweeps, title="swept parameters (means over seeds)")
        names.append("distance_bounds.png")
    return names
