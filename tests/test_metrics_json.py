"""metrics.json <-> the typed report (evaluation.metrics_json): a stored file read and written again gives the
same bytes, an undefined value is an Unavailable that carries its reason into report.md, and a damaged file is
one clear error naming the file and the key."""

from __future__ import annotations

import copy
import json

import pytest
from helpers.metrics import STORED, stored_metrics

from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import Unavailable
from msa_slam.evaluation.metrics_json import from_json
from msa_slam.evaluation.metrics_writer import to_json
from msa_slam.experiments.rows import METRICS
from msa_slam.io.tables import write_json
from msa_slam.pipeline import make_config
from msa_slam.reporting.comparison import COLUMNS as COMPARISON_COLUMNS
from msa_slam.reporting.report import report_markdown
from msa_slam.reporting.stored import StoredRun, read_run
from msa_slam.slam.loop_closing import REJECTION_REASONS

NO_REVISIT = "no keyframe pair within loop_radius of each other (made up for this test)"


@pytest.mark.parametrize("name", ["batch.json", "online.json", "comparison.json"])
def test_stored_metrics_round_trip_byte_for_byte(name, tmp_path):
    data = stored_metrics(name)
    written = [to_json(from_json(m, name)) for m in data] if isinstance(data, list) else to_json(from_json(data, name))
    write_json(tmp_path / name, written)
    assert (tmp_path / name).read_bytes() == (STORED / name).read_bytes()


def test_batch_and_online_are_told_apart_by_the_object():
    batch, online = from_json(stored_metrics("batch.json"), "b"), from_json(stored_metrics("online.json"), "o")
    assert not batch.online and batch.throughput is None and online.online and online.throughput.fps > 0
    assert isinstance(online.place_recognition.sweep, Unavailable)
    assert "batch pipeline" in batch.per_frame("fps").reason and online.per_frame("fps") == online.throughput.fps


def _without_pr(data: dict) -> dict:
    data = copy.deepcopy(data)
    data["pr_auc"] = data["f1_max"] = None
    data["unavailable"]["pr"] = NO_REVISIT
    return data


def test_unavailable_value_carries_its_reason_into_the_report():
    metrics = from_json(_without_pr(stored_metrics("batch.json")), "metrics.json")
    assert metrics.place_recognition.pr_auc == Unavailable(NO_REVISIT) == metrics.place_recognition.f1_max
    assert metrics.comparison_row(()).value("pr_auc") is None  # a table cell: n/a
    report = report_markdown(StoredRun(make_config(dataset="golden-seq"), metrics, None), [], set())
    assert "| n/a / n/a |" in report and f"- PR-AUC / F1-max n/a: {NO_REVISIT}\n" in report
    assert to_json(metrics)["pr_auc"] is None and to_json(metrics)["unavailable"]["pr"] == NO_REVISIT


@pytest.mark.parametrize("name", ["batch.json", "online.json"])
def test_table_rows_give_exactly_their_tables_columns_in_order(name):
    """The rows are built beside the tables' column lists (reporting.comparison.COLUMNS, experiments.rows.METRICS):
    a value added to one but not the other would be a CSV column without values, or a value no column shows."""
    metrics = from_json(stored_metrics(name), name)
    assert ["method", *metrics.comparison_row(REJECTION_REASONS).values] == list(COMPARISON_COLUMNS)
    assert [c for c in METRICS if c != "memory_vs_reference_pct"] == list(metrics.cell_values())


def test_experiment_row_names_the_reason_of_each_na_column():
    metrics = from_json(_without_pr(stored_metrics("batch.json")), "metrics.json")
    values = metrics.cell_values()
    assert values["pr_auc"].reason == NO_REVISIT and "batch pipeline" in values["fps"].reason


@pytest.mark.parametrize(
    "edit, key, problem",
    [
        (lambda m: m["full_rate"]["after"].pop("ate_translation_m"), "full_rate.after.ate_translation_m", "is missing"),
        (lambda m: m.pop("loop_accounting"), "loop_accounting", "is missing"),
        (lambda m: m.update(frames="214"), "frames", "must be an integer, not '214' (str)"),
        (lambda m: m["memory_bytes"].update(total=1.5), "memory_bytes.total", "must be an integer, not 1.5"),
        (lambda m: m.update(pr_auc=True), "pr_auc", "must be a number or null, not True (bool)"),
        (lambda m: m["threshold_sweep"][1].pop("candidates"), "threshold_sweep[1].candidates", "is missing"),
        (  # written when false_loops counted keyframes far apart: refused, not read with the new meaning
            lambda m: m["loop_accounting"].update(false_accepted=m["loop_accounting"].pop("distant_loops")),
            "loop_accounting.false_accepted",
            "is from an msa-slam that counted loops as false by their keyframes' ground-truth distance",
        ),
    ],
)
def test_bad_metrics_is_one_error_naming_the_file_and_key(edit, key, problem, tmp_path):
    data = stored_metrics("batch.json")
    edit(data)
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "metrics.json").write_text(json.dumps(data))
    with pytest.raises(InputError) as error:
        read_run(folder)
    message = str(error.value)
    assert message.startswith(f"{folder / 'metrics.json'}: metrics key {key!r} {problem}") and "\n" not in message
