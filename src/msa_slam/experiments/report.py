"""Aggregate a grid's finished cells into results.csv, results.md (the paper's Table II layout: per dataset,
one row per method with t./R. ATE improvement on the full-rate trajectory, F1-max, memory and time; mean
+- std over seeds, and with several seeds the per-seed ranks and MSA's paired-test verdicts) and report.md, with
the figures experiments.grid_figures draws."""

from __future__ import annotations

import json
import os
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from msa_slam.errors import InputError, error_line
from msa_slam.evaluation import NA, fmt
from msa_slam.evaluation.metrics import Unavailable, Value, known
from msa_slam.evaluation.run_metrics import RunMetrics
from msa_slam.experiments.cell_info import CellInfo
from msa_slam.experiments.folder import (
    GRID_FILE,
    FinishedCell,
    FinishedCells,
    cell_dir,
    experiment_grid,
    finished_list,
    stale_cells,
)
from msa_slam.experiments.grid import Cell
from msa_slam.experiments.grid_figures import write_figures
from msa_slam.experiments.rows import COLUMNS, METRICS, CellRow
from msa_slam.experiments.seeds import SEED_METRICS, seed_markdown, seed_summary
from msa_slam.io.atomic import write_text_atomic
from msa_slam.io.tables import rows_csv


def _group(info: CellInfo) -> tuple:
    """Cells compared with each other: same dataset, descriptor, grid parameters and seed."""
    return info.dataset, info.descriptor, json.dumps(info.parameters, sort_keys=True), info.seed


def make_rows(cells: list[FinishedCell], reference: str = "all") -> list[CellRow]:
    """One row per cell (COLUMNS); memory relative to the reference method of the same group; `reasons`: why each
    n/a column is (the values' own reasons)."""
    ref_memory = {_group(c.info): c.metrics.memory.accounted.total for c in cells if c.info.method == reference}
    rows = []
    for c in cells:
        info, m = c.info, c.metrics
        values = {
            **m.cell_values(),
            "memory_vs_reference_pct": _relative_memory(m, ref_memory.get(_group(info)), reference),
        }
        rows.append(
            CellRow(
                info.id,
                info.pipeline,
                info.dataset,
                info.descriptor,
                info.method,
                info.sampler,
                info.seed,
                _parameters(info.parameters),
                {column: known(values[column]) for column in METRICS},
                {column: value.reason for column, value in values.items() if isinstance(value, Unavailable)},
                info.parameters.get("mode", m.run.mode),
                info.swept,
            )
        )
    return rows


def _relative_memory(m: RunMetrics, ref_memory: int | None, reference: str) -> Value:
    """The cell's accounted memory in % of the reference method's in the same group, or why there is none."""
    if ref_memory:
        return 100.0 * m.memory.accounted.total / ref_memory
    return Unavailable(
        f"the `{reference}` cell of this dataset, descriptor, parameters and seed has 0 bytes"
        if ref_memory == 0
        else f"no finished `{reference}` cell of this dataset, descriptor, parameters and seed to compare with"
    )


def _parameters(parameters: Mapping[str, Any]) -> str:
    """A cell's grid parameters as its row (and its section of results.md) shows them."""
    return json.dumps(parameters, sort_keys=True) if parameters else ""


def _failed_row(cell: Cell, error_file: Path) -> CellRow:
    """results.md's row of a cell that failed (its traceback in `error_file`): every value n/a, the error as the
    reason, so that a method whose cells failed is shown, with why, not left out of the table."""
    reason = f"the cell failed with {error_line(error_file)} (traceback in errors/<cell id>.txt)"
    return CellRow(
        cell.id,
        cell.pipeline,
        cell.dataset,
        cell.descriptor,
        cell.method,
        cell.sampler,
        cell.seed,
        _parameters(cell.parameters),
        dict.fromkeys(METRICS),
        dict.fromkeys(METRICS, reason),
    )


def _seed_lines(methods: dict[str, list[CellRow]]) -> list[str]:
    """Per-seed ranks and MSA's paired-test verdicts of one section (nothing with a single seed)."""
    by_seed: dict[int, list[CellRow]] = defaultdict(list)
    for rs in methods.values():
        for r in rs:
            by_seed[r.seed].append(r)
    if len(by_seed) < 2:
        return []
    return ["Spread over seeds:", "", seed_markdown(seed_summary(dict(sorted(by_seed.items())))), ""]


def _mean(rows: list[CellRow], key: str) -> tuple[float, float | None] | None:
    """Mean and sample std (None below 2 values) of the available values; None when there are none."""
    values = [v for v in (r.value(key) for r in rows) if v is not None]
    if not values:
        return None
    return float(np.mean(values)), float(np.std(values, ddof=1)) if len(values) > 1 else None


def _cell(stat: tuple[float, float | None] | None, spec: str, unit: str = "") -> str:
    if stat is None:
        return NA
    return fmt(stat[0], spec) + (f" ± {fmt(stat[1], spec)}" if stat[1] is not None else "") + unit


@dataclass
class _Missing:
    """The columns one reason leaves n/a in a section, and on which seeds of which methods."""

    columns: set[str] = field(default_factory=set)
    who: defaultdict[str, set[int]] = field(default_factory=lambda: defaultdict(set))


def _na_notes(methods: dict[str, list[CellRow]], labels: dict[str, str]) -> list[str]:
    """One line per reason for the section's n/a values among the `labels` columns (column -> label shown),
    naming the columns and who lacks them (with several seeds, on which seeds when not on all of a method's:
    its mean is then over the others)."""
    ran = {m: {r.seed for r in rs} for m, rs in methods.items()}  # the seeds each method has a row on
    found: dict[str, _Missing] = {}  # reason -> the columns it leaves n/a, and where
    for method, rs in methods.items():
        for r in rs:
            for column, reason in sorted(r.reasons.items()):
                if column in labels:
                    entry = found.setdefault(reason, _Missing())
                    entry.columns.add(column)
                    entry.who[method].add(r.seed)
    several = len(set().union(*ran.values())) > 1
    lines = []
    for reason, entry in found.items():
        who = entry.who
        if who == ran:
            whom = "every method" + (" and seed" if several else "")
        else:
            whom = "; ".join(
                m if who[m] == ran[m] else f"{m} on seed(s) {', '.join(map(str, sorted(who[m])))}" for m in who
            )
        named = (
            "every value"
            if entry.columns >= set(labels)  # a failed cell's
            else ", ".join(label for column, label in labels.items() if column in entry.columns)
        )
        lines.append(f"- {named} n/a ({whom}): {reason}")
    if not lines:
        return []
    return [
        f"Notes (n/a values{'; a mean leaves out the seeds where its value is n/a' if several else ''}):",
        "",
        *lines,
        "",
    ]


def table2_markdown(rows: list[CellRow]) -> str:
    """The paper's Table II layout, one section per dataset/descriptor (and grid parameters); means over seeds."""
    sections: dict[tuple, dict[str, list[CellRow]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        sections[(r.dataset, r.descriptor, r.parameters)][r.method].append(r)
    shown = {
        "keyframes": "keyframes",
        "improvement_t_pct": "t. ATE impr. (full rate)",
        "improvement_r_pct": "R. ATE impr. (full rate)",
        "f1_max": "F1-max",
        "memory_mib": "mem.",
        "memory_vs_reference_pct": "mem. vs ref.",
        "time_s": "time",
        "fps": "frames/s",
        "backend_p99_ms": "back-end p99",
    }
    head = ["method", *shown.values()]
    lines = []
    for (dataset, descriptor, params), methods in sections.items():
        seeds = max(len(v) for v in methods.values())
        lines += [
            f"### {dataset} ({descriptor}{', ' + params if params else ''}; {seeds} seed(s))",
            "",
            "| " + " | ".join(head) + " |",
            "|" + "---|" * len(head),
        ]
        for method, rs in methods.items():
            lines.append(
                "| "
                + " | ".join(
                    [
                        method,
                        _cell(_mean(rs, "keyframes"), ".0f"),
                        _cell(_mean(rs, "improvement_t_pct"), ".1f", " %"),
                        _cell(_mean(rs, "improvement_r_pct"), ".1f", " %"),
                        _cell(_mean(rs, "f1_max"), ".3f"),
                        _cell(_mean(rs, "memory_mib"), ".2f", " MiB"),
                        _cell(_mean(rs, "memory_vs_reference_pct"), ".0f", " %"),
                        _cell(_mean(rs, "time_s"), ".1f", " s"),
                        _cell(_mean(rs, "fps"), ".1f"),
                        _cell(_mean(rs, "backend_p99_ms"), ".1f", " ms"),
                    ]
                )
                + " |"
            )
        lines.append("")
        spread = _seed_lines(methods)
        lines += spread
        lines += _na_notes(
            methods, {**({k: label for k, (label, _) in SEED_METRICS.items()} if spread else {}), **shown}
        )
    return "\n".join(lines)


def write_report(
    results_dir: str | os.PathLike,
    reference: str | None = None,
    finished: FinishedCells | None = None,
    rerun: Sequence[str] = (),
) -> Path:
    """Write results.csv, results.md, figures/ and report.md into `results_dir` from the finished cells of its
    grid.yaml (results.md also shows the failed ones: n/a, with their error in its notes); return report.md.
    `reference` (default: the grid's) must be one of the grid's methods. `finished`: cells already read from
    this folder (folder.finished_cells, by a resume), not read again; `rerun`: the lines of the cells this run
    redid because their data or code had changed (identity.outdated_cells), listed in report.md."""
    out = Path(results_dir)
    grid, expected = experiment_grid(out)
    methods = grid.labels()
    if reference is None:
        reference = grid.reference_method()
    elif reference not in methods:
        raise InputError(f"--reference {reference!r}: not a method of this experiment; available: {', '.join(methods)}")
    cells = finished_list(out, expected, finished)
    rows = make_rows(cells, reference)
    write_text_atomic(out / "results.csv", rows_csv([r.record() for r in rows], COLUMNS))
    done = {c.info.id for c in cells}
    failed_cells = [c for c in expected if c.id not in done and (out / "errors" / f"{c.id}.txt").is_file()]
    failed = [c.id for c in failed_cells]
    order = {c.id: i for i, c in enumerate(expected)}
    shown = rows + [_failed_row(c, out / "errors" / f"{c.id}.txt") for c in failed_cells]
    table = table2_markdown(sorted(shown, key=lambda r: order[r.cell]))
    write_text_atomic(out / "results.md", table)
    figures = write_figures(cells, rows, reference, out / "figures") if rows else []
    damaged = [c.id for c in expected if c.id not in done and c.id not in failed and cell_dir(out, c.id).is_dir()]
    stale = stale_cells(out, expected)
    lines = [
        f"# Experiment results: {out.name}",
        "",
        f"{len(rows)} of {len(expected)} cell(s) finished"
        + (f", {len(failed)} failed (see errors/)" if failed else "")
        + ". "
        "ATE improvement: 100 (before - after) / before of the full-rate trajectory (every frame, posed from "
        "the keyframe before it; SE(3)-aligned); memory: "
        f"accounted bytes of keyframe clouds, descriptors and graph (vs the `{reference}` method); time: "
        "back-end seconds (everything after odometry); p99: per-frame back-end latency.",
        "",
    ]
    if failed:
        lines += ["Failed cells: " + ", ".join(failed), ""]
    if damaged:
        lines += [
            "Cells left out, their cell.json or metrics.json unreadable (run the experiment again to redo "
            "them): " + ", ".join(f"cells/{cell}" for cell in damaged),
            "",
        ]
    if stale:
        lines += [
            f"Stale cells (from an earlier grid, not in {GRID_FILE}; left out of every aggregate): " + ", ".join(stale),
            "",
        ]
    if rerun:
        lines += ["Cells rerun by this run, their earlier results left out:", *(f"- {line}" for line in rerun), ""]
    lines.append(table)
    lines += [f"![{n}](figures/{n})" for n in figures]
    lines += ["", "Per-cell results: cells/<id>/report.md; all rows: results.csv.", ""]
    write_text_atomic(out / "report.md", "\n".join(lines))
    return out / "report.md"
