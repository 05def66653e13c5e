"""Finished results read back from their folders: what their report.md is made of, so `msa-slam report` can
write it again from the files alone, without running anything (experiments.rereport)."""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msa_slam.errors import InputError, error_line
from msa_slam.evaluation.metrics_json import from_json
from msa_slam.evaluation.resources import StageTimer
from msa_slam.evaluation.run_metrics import RunMetrics
from msa_slam.io.poses import read_poses
from msa_slam.pipeline.config import OnlineConfig, RunConfig, make_config, make_online_config, read_config_file

COMPARE_FIGURES = ("metrics.png", "trajectories.png", "pr_curves.png", "pr_curves_reference.png")  # report order


@dataclass(frozen=True)
class StoredRun:
    """One run's config, metrics and ground truth as its folder holds them (reporting.report.ReportedRun)."""

    config: Any
    metrics: RunMetrics
    gt_poses: np.ndarray | None

    @property
    def measured(self) -> RunMetrics:
        """The run's report (reporting.report.ReportedRun: a fresh RunResult's, once measured, or this one)."""
        return self.metrics


@dataclass
class StoredFrontend:
    """A comparison's shared front end as its report describes it, from the metrics every method records."""

    name: str
    frames: int
    timer: StageTimer
    cached: dict[str, bool]

    def __len__(self) -> int:
        return self.frames


def read_text(path: Path) -> str:
    """A file a result folder must hold; a missing one is one clear error naming it."""
    try:
        return path.read_text()
    except OSError as exc:
        raise InputError(f"{path}: cannot read it ({exc.strerror}); the result folder is incomplete") from None


def read_json(path: Path) -> Any:
    """A JSON file a result folder must hold (read_text); a damaged one is one clear error naming it."""
    try:
        return json.loads(read_text(path))
    except ValueError as exc:
        raise InputError(f"{path}: not valid JSON ({exc}); the result folder is damaged") from None


def read_run(folder: Path) -> StoredRun:
    """The run in `folder` (of `run`, `online`, or a method of a comparison)."""
    path = folder / "metrics.json"
    metrics = from_json(read_json(path), str(path))
    data = read_config_file(folder / "config.yaml", OnlineConfig if metrics.online else RunConfig)
    config = make_online_config(data) if metrics.online else make_config(data)
    return StoredRun(config, metrics, _ground_truth(folder, metrics.run.frames))


def _ground_truth(folder: Path, frames: int) -> np.ndarray | None:
    """trajectories/gt.kitti, written when every frame had a ground-truth pose; else NaN poses when frames.csv
    shows some ground truth (the report then says which metrics need it all), None when it shows none."""
    path = folder / "trajectories" / "gt.kitti"
    if path.is_file():
        return read_poses(path, "kitti")[0]
    some = any(row["gt_x"] for row in csv.DictReader(read_text(folder / "frames.csv").splitlines()))
    return np.full((frames, 4, 4), np.nan) if some else None


def listed_methods(folder: Path) -> list[RunMetrics]:
    """The reports of the methods a comparison folder's comparison.json lists, in the comparison's order."""
    path = folder / "comparison.json"
    methods = read_json(path)
    if not isinstance(methods, list):
        raise InputError(f"{path}: not a list of the methods' metrics; the result folder is damaged")
    return [from_json(m, f"{path} (method {i + 1})") for i, m in enumerate(methods)]


def read_comparison(folder: Path) -> tuple[StoredFrontend, list[StoredRun]]:
    """The front end and the finished methods (in the comparison's order) of a comparison folder."""
    listed = listed_methods(folder)
    if not listed:
        raise InputError(
            f"{folder}: no method of this comparison finished (comparison.json lists none); nothing to report"
        )
    runs = [read_run(folder / "runs" / m.method) for m in listed]
    first = runs[0].metrics
    frontend_s, cached = first.timing.frontend_s, first.timing.frontend_cached
    if frontend_s is None or cached is None:
        raise InputError(f"{folder}: its methods' metrics.json lack the front end's timing (not a comparison's runs)")
    timer = StageTimer()
    timer.seconds = dict(frontend_s)
    return StoredFrontend(first.run.sequence, first.run.frames, timer, dict(cached)), runs


def failed_methods(folder: Path, order: Sequence[str] = ()) -> dict[str, str]:
    """Method -> `Type: message` of the comparison's methods that failed (their runs/<method>/error.txt), the
    methods of `order` first in that order (the paper's: experiments.compare.PAPER_METHODS), others after by
    name."""
    order = list(order)
    names = sorted(
        (p.parent.name for p in (folder / "runs").glob("*/error.txt")),
        key=lambda name: (order.index(name) if name in order else len(order), name),
    )
    return {name: error_line(folder / "runs" / name / "error.txt") for name in names}


def comparison_figures(folder: Path) -> list[str]:
    """The comparison's figures present in figures/, in its report's order."""
    return [name for name in COMPARE_FIGURES if (folder / "figures" / name).is_file()]
