"""A recording without ground truth runs (realistic mode): keyframes, loops and trajectories, with ATE, RPE
and PR reported n/a and why; the oracle mode and sampling on ground truth are refused before any work."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.metrics import metrics_json
from test_report_any_folder import _report_again

from msa_slam.errors import InputError
from msa_slam.pipeline import LiveFrontEnd, run
from msa_slam.pipeline.config import make_online_config
from msa_slam.sources import open_source


def test_online_without_ground_truth_reports_na(scans_only):
    folder, poses = scans_only
    config = make_online_config(
        dataset=str(folder), mode="realistic", odometry=str(poses), sampler="constant", sampler_params={"distance": 1.0}
    )
    source = open_source(config.dataset, mode=config.mode)
    assert source.gt_poses is None and len(source) == 90
    result = run(config, LiveFrontEnd(source))
    m = metrics_json(result)
    assert result.gt_poses is None and m["keyframes"] >= 3
    assert m["before"]["ate_translation_m"] is None and m["after"]["ate_translation_m"] is None
    assert m["unavailable"]["ate"] == "no ground truth"
    assert m["pr_auc"] is None and "no ground truth" in m["unavailable"]["pr"]
    assert np.isfinite(result.optimised).all()


def test_oracle_and_gt_sampling_refused_without_ground_truth(scans_only):
    folder, poses = scans_only
    with pytest.raises(InputError, match="oracle mode needs.*--mode realistic"):
        open_source(str(folder), mode="oracle")
    config = make_online_config(dataset=str(folder), mode="realistic", odometry=str(poses), sample_on="gt")
    source = open_source(str(folder), mode="realistic")
    with pytest.raises(InputError, match="sample_on=gt but the frames have no ground-truth poses"):
        run(config, LiveFrontEnd(source))


@pytest.mark.parametrize("command", ["run", "compare", "online"])
def test_cli_commands_write_results_without_ground_truth(command, scans_only, tmp_path):
    """Batch, compare and online write a complete result folder from scans alone: no ground-truth files,
    ATE n/a with the reason, loops not judged true or false."""
    import csv
    import json
    import re

    from typer.testing import CliRunner

    from msa_slam.cli import app

    folder, poses = scans_only
    out = tmp_path / command
    extra = [] if command == "compare" else ["--sampler", "constant", "-p", "distance=1.0"]
    result = CliRunner().invoke(
        app,
        [
            command,
            "--dataset",
            str(folder),
            "--mode",
            "realistic",
            "--odometry",
            str(poses),
            *extra,
            "--out",
            str(out),
            "--quiet",
        ],
    )
    assert result.exit_code == 0, result.output
    run = out / "runs" / "msa" if command == "compare" else out
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["unavailable"]["ate"] == "no ground truth"
    assert not list((run / "trajectories").glob("gt*"))
    report = (run / "report.md").read_text()
    assert "ATE (and its % improvement) n/a: no ground truth" in report
    assert "ATE alignment: n/a (no ground truth" in report and "evo_ape" not in report
    tops = [run / "report.md"] + ([out / "report.md"] if command == "compare" else [])
    for page in tops:
        text = page.read_text()
        assert "None" not in text, page
        named = set(re.findall(r"\b((?:figures|trajectories|runs)/[\w./-]*\w)", text))
        assert named and all((page.parent / name).exists() for name in named), (page, named)
    if command == "compare":
        assert "No ground truth: ATE, RPE, PR-AUC / F1-max and false loops are n/a" in tops[1].read_text()
    rows = list(csv.DictReader((run / "frames.csv").open()))
    assert len(rows) == 90 and all(r["gt_x"] == "" for r in rows)
    assert all(r["false_loop"] == "n/a" for r in csv.DictReader((run / "loops.csv").open()))
    if command != "compare":  # `msa-slam report` on the folder (test_report_any_folder.py), on this same run
        report = (out / "report.md").read_text()
        assert "ATE alignment: n/a (no ground truth, so no ATE to align and no ground-truth trajectory" in report
        named = set(re.findall(r"trajectories/[\w.]+", report))
        assert named and all((out / name).is_file() for name in named)
        assert "ground truth, odometry" not in report
        _report_again(out)
