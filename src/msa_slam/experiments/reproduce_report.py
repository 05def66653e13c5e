"""report.md of `msa-slam reproduce`: the sections "Table I", "Table II", "Ablations", "Distance bounds" and
"Claims" from the finished cells of the four paper grids, each table stamped with its conditions, and the
figures beside it. Missing grids (not run, or run with --presets leaving them out) make a section that says so."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from msa_slam.evaluation.display import fmt
from msa_slam.evaluation.spread import MIN_SEEDS, PAIRED_TEST, ROUNDING
from msa_slam.experiments import paper_claims as pc
from msa_slam.experiments.grid import GridSpec, slug
from msa_slam.experiments.paper import NOT_REPRODUCED, STAND_INS, column_of, dataset_name
from msa_slam.experiments.paper_values import GridValues, aligned_paths, memory_over_distance
from msa_slam.experiments.rows import CellRow
from msa_slam.experiments.verdicts import extrapolate

SECTIONS = ("Table I", "Table II", "Ablations", "Distance bounds", "Claims")
# column -> (label, decimals, unit) of the per-method tables
ACCURACY = {"improvement_t_pct": ("t. ATE impr.", 1, " %"), "improvement_r_pct": ("R. ATE impr.", 1, " %")}
ONLINE = {
    "keyframes": ("keyframes", 0, ""),
    **ACCURACY,
    "f1_max": ("F1-max", 3, ""),
    "memory_mib": ("memory", 1, " MiB"),
    "memory_vs_reference_pct": ("mem. vs all", 0, " %"),
    "time_s": ("time", 1, " s"),
}
BATCH = {
    **ACCURACY,
    "pr_auc": ("PR-AUC", 3, ""),
    "memory_vs_reference_pct": ("mem. vs all", 0, " %"),
    "time_s": ("time", 1, " s"),
}


@dataclass(frozen=True)
class Run:
    """One paper grid as run: its (possibly --quick/--seeds) spec, values, and its folder relative to report.md."""

    grid: GridSpec
    values: GridValues
    folder: str


def mean_cell(values: Sequence[float | None], digits: int, unit: str = "") -> str:
    known = [float(x) for x in values if x is not None]
    if not known:
        return "n/a"
    spec = f".{digits}f"  # fmt: a value that rounds to zero shows unsigned
    if len(known) == 1:
        return fmt(known[0], spec, unit)
    return f"{fmt(float(np.mean(known)), spec)} ± {fmt(float(np.std(known, ddof=1)), spec)}{unit}"


def method_table(rows: Sequence[CellRow], columns: Mapping[str, tuple[str, int, str]]) -> list[str]:
    """One line per method (first appearance order): mean ± sample std over its rows of every column."""
    by_method: dict[str, list[CellRow]] = defaultdict(list)
    for r in rows:
        by_method[r.method].append(r)
    lines = [
        "| method | runs | " + " | ".join(label for label, _, _ in columns.values()) + " |",
        "|" + "---|" * (len(columns) + 2),
    ]
    for m, rs in by_method.items():
        lines.append(
            f"| {m} | {len(rs)} | "
            + " | ".join(mean_cell([r.value(c) for r in rs], d, u) for c, (_, d, u) in columns.items())
            + " |"
        )
    return lines + [""]


def conditions(run: Run, extra: str = "") -> str:
    """The line naming what a table was measured under."""
    rows, base = run.values.rows, run.grid.base
    seeds = sorted({r.seed for r in rows})
    frames = {column_of(r.dataset): r.value("frames") for r in rows}
    modes = sorted({r.mode for r in rows})
    solver = "LM at the end" if run.grid.pipeline == "batch" else "iSAM2 every frame"
    return (
        f"Conditions: {run.grid.pipeline} protocol ({solver}); "
        f"odometry {base.get('odometry', 'kiss')}; {' and '.join(modes) or 'no'} mode; seeds "
        f"{', '.join(map(str, seeds)) or 'none'}; frames "
        + ", ".join(f"{k} {v}" for k, v in frames.items())
        + "; ATE on the full-rate trajectory, SE(3)-aligned (Umeyama, no scale); mean ± sample std over seeds"
        + f"; values differing only by floating-point rounding (within {ROUNDING:g} of their scale) are shown as "
        "equal (difference 0.0)"
        + (f"; {extra}" if extra else "")
        + f". Cells and per-dataset tables: {run.folder}/results.md."
    )


def _missing(name: str) -> list[str]:
    return [f"Not run: the grid {name} was left out (--presets) or has no finished cell.", ""]


def _by(rows: Sequence[CellRow], key: Callable[[CellRow], Any]) -> dict[Any, list[CellRow]]:
    out: dict[Any, list[CellRow]] = defaultdict(list)
    for r in rows:
        out[key(r)].append(r)
    return out


def stand_in_lines(runs: Mapping[str, Run]) -> list[str]:
    names = dict.fromkeys(dataset_name(r.dataset) for run in runs.values() for r in run.values.rows)
    lines = ["| paper column | simulated sequence | why this one |", "|---|---|---|"]
    lines += [f"| {STAND_INS[n].column} | {n} | {STAND_INS[n].why} |" for n in names if n in STAND_INS]
    return lines + ["", "Not reproduced:", "", *(f"- {line}" for line in NOT_REPRODUCED), ""]


def table1(run: Run | None, figures: list[str]) -> list[str]:
    lines = ["## Table I", ""]
    if run is None or not run.values.rows:
        return lines + _missing("paper-table1")
    lines += [conditions(run, "Scan Context at 0.8, 3 m truth radius, small_gicp verification"), ""]
    for mode, rows in _by(run.values.rows, lambda r: r.mode).items():
        lines += [f"### {mode} mode: t. ATE improvement per dataset [%]", ""]
        datasets = list(dict.fromkeys(r.dataset for r in rows))
        by_method = _by(rows, lambda r: r.method)
        lines += ["| method | " + " | ".join(column_of(d) for d in datasets) + " |", "|" + "---|" * (len(datasets) + 1)]
        lines += [
            f"| {m} | "
            + " | ".join(mean_cell([r.value("improvement_t_pct") for r in rs if r.dataset == d], 1) for d in datasets)
            + " |"
            for m, rs in by_method.items()
        ]
        lines += ["", f"All datasets of {mode} mode pooled:", "", *method_table(rows, BATCH)]
        tests = ["| baseline | t. ATE impr. MSA - baseline | R. ATE impr. MSA - baseline |", "|---|---|---|"]
        for base in by_method:
            if base != "msa":
                found = [pc.v.difference(*pc.paired(rows, pc.method("msa"), pc.method(base), c)) for c in ACCURACY]
                tests.append(f"| {base} | " + " | ".join(f.text() for f in found) + " |")
        lines += [f"MSA against each baseline ({mode}), paired over (dataset, seed): {PAIRED_TEST}.", "", *tests, ""]
    return lines + [f"![{n}](figures/{n})" for n in figures] + [""]


def memory_growth(run: Run) -> tuple[dict[str, dict[int, float]], dict[str, tuple[np.ndarray, np.ndarray]], str]:
    """Per method and seed, the accounted memory extrapolated to pc.TARGET_M [GiB] on the long drive (the grid's
    first dataset), the first seed's series for the figure, and that dataset."""
    drive = run.grid.datasets[0]
    cells = [c for c in run.values.cells if c.info.dataset == drive]
    out: dict[str, dict[int, float]] = defaultdict(dict)
    series = {}
    first = min((c.info.seed for c in cells), default=None)
    for c in cells:
        found = memory_over_distance(c)
        if found is None:
            continue
        try:
            out[c.info.method][c.info.seed] = extrapolate(*found, pc.TARGET_M) / 2**30
        except ValueError:
            continue
        if c.info.seed == first:
            series[c.info.method] = found
    return out, series, drive


def table2(run: Run | None, figures: list[str], growth: Mapping[str, Mapping[int, float]]) -> list[str]:
    lines = ["## Table II", ""]
    if run is None or not run.values.rows:
        return lines + _missing("paper-table2")
    lines += [conditions(run), ""]
    for dataset, rows in _by(run.values.rows, lambda r: r.dataset).items():
        lines += [f"### {column_of(dataset)} (`{dataset}`)", "", *method_table(rows, ONLINE)]
    lines += [
        f"Accounted memory extrapolated to {pc.TARGET_M / 1000:.0f} km on the long drive (a straight line "
        "through the second half of each run's memory against ground-truth distance), GiB:",
        "",
        "| method | extrapolated |",
        "|---|---|",
    ]
    lines += [f"| {m} | {pc.stat(list(by_seed.values()), 1, ' GiB')} |" for m, by_seed in growth.items()]
    return lines + [""] + [f"![{n}](figures/{n})" for n in figures] + [""]


def ablations(run: Run | None) -> list[str]:
    lines = ["## Ablations", ""]
    if run is None or not run.values.rows:
        return lines + _missing("paper-ablation")
    lines += [conditions(run, "alpha = 10 emphasises pi and beta = 10 rho in the score (alpha + rho)/(beta + pi)"), ""]
    for dataset, rows in _by(run.values.rows, lambda r: r.dataset).items():
        lines += [f"### {column_of(dataset)}", "", *method_table(rows, ONLINE)]
    return lines


def bounds(run: Run | None, figures: list[str]) -> list[str]:
    lines = ["## Distance bounds", ""]
    if run is None or not run.values.rows:
        return lines + _missing("paper-bounds")
    swept = "lambda_l swept with lambda_u = 5, lambda_u swept with lambda_l = 0.1 (multiples of the mean step, eq. 7)"
    lines += [conditions(run, swept), ""]
    columns = {k: ONLINE[k] for k in ("improvement_t_pct", "improvement_r_pct", "f1_max", "memory_vs_reference_pct")}
    for dataset, rows in _by(run.values.rows, lambda r: r.dataset).items():
        lines += [f"### {column_of(dataset)}", "", *method_table(rows, columns)]
    return lines + [f"![{n}](figures/{n})" for n in figures] + [""]


def claims_lines(claims: Sequence[pc.Claim]) -> list[str]:
    lines = [
        "## Claims",
        "",
        "Verdicts: holds / does not hold / not separable (the difference is within the seed spread: paired "
        f"t-test p >= 0.05, or mean ± std straddles the threshold; a test needs at least "
        f"{MIN_SEEDS} seeds). Rules: msa_slam/experiments/verdicts.py.",
        "",
        "| claim | verdict | numbers | conditions |",
        "|---|---|---|---|",
    ]
    lines += [f"| {c.claim} | **{c.verdict}** | {c.numbers} | {c.conditions} |" for c in claims]
    return lines + [""]


def figure_name(text: str) -> str:
    return f"{slug(text)}.png"


def fig6_panels(run: Run, dataset: str) -> tuple[np.ndarray, list] | None:
    """Ground truth and the odometry, entropy and MSA panels of the first seed's oracle run on `dataset`: every
    frame's trajectory SE(3)-aligned to ground truth and coloured by its error, the keyframes as rings (the
    paper's Fig. 6 compares MSA and entropy after optimisation with the raw odometry)."""
    from msa_slam.viz import TrajectoryPanel

    cells = {
        c.info.method: c
        for c in run.values.cells
        if c.info.dataset == dataset
        and c.metrics.run.mode == "oracle"
        and c.info.seed == min(r.seed for r in run.values.rows)
    }
    if "msa" not in cells or "entropy" not in cells:
        return None
    msa, entropy = aligned_paths(cells["msa"]), aligned_paths(cells["entropy"])
    if msa is None or entropy is None:
        return None
    found = {"msa": msa, "entropy": entropy}
    gt, odometry = found["msa"][0], found["msa"][1]["odometry"]
    panels = [TrajectoryPanel("KISS-ICP odometry", odometry.xy, odometry.errors, keyframes=())]
    for m in ("entropy", "msa"):  # loops given (none drawn): the methods the colour scale and the zoom are about
        _, paths, keyframes = found[m]
        path = paths["optimised"]
        panels.append(
            TrajectoryPanel(
                f"{m} after optimisation, ATE {float(np.sqrt(np.mean(path.errors**2))):.2f} m",
                path.xy,
                path.errors,
                (),
                keyframes=keyframes,
            )
        )
    return gt, panels


def missing_parts(text: str, min_claims: int = 6) -> list[str]:
    """What a report.md of reproduce lacks: any of SECTIONS as a "## " heading, or `min_claims` verdict rows in
    its Claims table (the CI's and the slow test's check of a finished run)."""
    headings = {line[3:].strip() for line in text.splitlines() if line.startswith("## ")}
    missing = [f"section {name!r}" for name in SECTIONS if name not in headings]
    claims = text.split("## Claims", 1)[1] if "## Claims" in text else ""
    rows = [line for line in claims.splitlines() if line.startswith("| ") and " | **" in line]
    if len(rows) < min_claims:
        missing.append(f"{min_claims} claim rows (found {len(rows)})")
    return missing
