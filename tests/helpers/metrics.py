"""Runs' reports for tests: as the metrics.json they write, edited, and the stored samples of tests/data/metrics/
(metrics.json of the golden input's `run`, `online` and `compare`, written by msa-slam itself)."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from msa_slam.evaluation.metrics_json import from_json
from msa_slam.evaluation.metrics_writer import to_json
from msa_slam.evaluation.run_metrics import ComparisonRow
from msa_slam.experiments.seeds import SEED_METRICS
from msa_slam.slam import RunResult

STORED = Path(__file__).parent.parent / "data" / "metrics"


def metrics_json(result: RunResult) -> dict[str, Any]:
    """The run's report as metrics.json holds it (without the stamp the result folder adds)."""
    return to_json(result.metrics)


def edited(result: RunResult, change: Callable[[dict[str, Any]], None]) -> RunResult:
    """`result` with its report changed through its JSON form (`change` edits the dict in place)."""
    data = copy.deepcopy(to_json(result.metrics))
    change(data)
    return replace(result, metrics=from_json(data, "edited metrics"))


def stored_metrics(name: str) -> Any:
    """A stored metrics.json (batch.json, online.json) or comparison.json of tests/data/metrics/, as JSON."""
    return json.loads((STORED / name).read_text())


def seed_row(method: str, **values: float | None) -> ComparisonRow:
    """A comparison row of `method` with the given seed-table values, every other SEED_METRICS column n/a."""
    return ComparisonRow(method, {column: values.get(column) for column in SEED_METRICS})
