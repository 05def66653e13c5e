"""The demo's closing lines: per method what its run found, the numbers those of the methods' metrics.json, and
that one world seed cannot tell whether the differences exceed the seed spread (`msa-slam reproduce` can)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

import msa_slam.demo
from msa_slam.cli import app
from msa_slam.evaluation import fmt
from msa_slam.experiments.compare import run_compare
from msa_slam.pipeline import make_config
from msa_slam.reporting.findings import findings

METHODS = (("all", "all", {}), ("constant-2m", "constant", {"distance": 2.0}), ("msa", "msa", {}))
LINE = re.compile(
    r"^  (?P<method>\S+) +(?P<keyframes>\d+) keyframes \((?P<share>\S+) % of frames\), memory "
    r"(?P<memory>\S+) % of all samples, t\. ATE improvement (?P<ate>\S+) %, (?P<loops>\d+) loops, "
    r"PR-AUC (?P<pr_auc>\S+)$"
)


@pytest.fixture(scope="module")
def report(sequence, odometry_file, cache_dir, tmp_path_factory) -> Path:
    """A short demo-like run: the demo's settings (Scan Context, oracle loops, no sweep) on the test sequence."""
    config = make_config(
        dataset=str(sequence), odometry=str(odometry_file), descriptor="sc", mode="oracle", cache_dir=str(cache_dir)
    )
    return run_compare(
        config, tmp_path_factory.mktemp("demo-like") / "cmp", methods=METHODS, sweep=False, figures=False
    )


def test_the_closing_lines_give_each_methods_metrics(report):
    lines = findings(report.parent)
    rows = [LINE.match(line) for line in lines[1:-1]]
    assert all(rows) and [r["method"] for r in rows] == [name for name, _, _ in METHODS]
    metrics = {name: json.loads((report.parent / "runs" / name / "metrics.json").read_text()) for name, _, _ in METHODS}
    everything = metrics["all"]["memory_bytes"]["total"]
    for row in rows:
        m = metrics[row["method"]]
        assert int(row["keyframes"]) == m["keyframes"] and int(row["loops"]) == m["verified"]
        assert row["share"] == f"{100 * m['keyframes'] / m['frames']:.1f}"
        assert row["memory"] == f"{100 * m['memory_bytes']['total'] / everything:.1f}"
        assert row["ate"] == fmt(m["full_rate"]["improvement_pct"]["translation"], ".1f")
        assert row["pr_auc"] == fmt(m["pr_auc"], ".3f")
    assert rows[0]["memory"] == "100.0" and rows[0]["share"] == "100.0"
    assert f"{metrics['all']['frames']} frames" in lines[0]


def test_the_closing_sentence_says_one_seed_cannot_tell(report):
    last = findings(report.parent)[-1]
    assert "cannot be told" in last and "1 world seed" in last and "at least 3" in last
    assert "`msa-slam reproduce`" in last


def test_the_demo_command_ends_with_them(report, monkeypatch):
    monkeypatch.setattr(msa_slam.demo, "run_demo", lambda *args, **kwargs: report)
    result = CliRunner().invoke(app, ["demo", "--quiet"])
    assert result.exit_code == 0, result.output
    assert result.output.splitlines() == [f"report: {report}", *findings(report.parent)]
