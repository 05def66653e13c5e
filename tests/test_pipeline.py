"""Batch pipeline on the small simulated figure-eight (msa_slam.sim's "test" sequence).

Odometry is the ground truth with a constant yaw bias and 1 % scale error (a pose file; fixtures in
conftest.py), so the tests need no KISS-ICP and the drift is known: loops at the crossing must pull the
trajectory back.
"""

from __future__ import annotations

import csv
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import drifted
from helpers.metrics import edited, metrics_json
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.errors import InputError
from msa_slam.evaluation.loops import is_false_loop
from msa_slam.evaluation.run_metrics import ComparisonRow
from msa_slam.experiments.compare import run_compare
from msa_slam.experiments.sweep import threshold_sweep
from msa_slam.io.poses import read_poses, write_poses
from msa_slam.pipeline import apply_params, make_config, prepare_frontend, run
from msa_slam.reporting.comparison import COLUMNS, table_markdown, table_row
from msa_slam.reporting.results import loop_edges, loops_csv, write_run


@pytest.fixture(scope="session")
def base(sequence, odometry_file, cache_dir):
    return make_config(
        dataset=str(sequence),
        odometry=str(odometry_file),
        cache_dir=str(cache_dir),
        sampler="constant",
        sampler_params={"distance": 3.0},
    )


@pytest.fixture(scope="session")
def frontend(base):
    return prepare_frontend(base)


@pytest.fixture(scope="module")
def swept(base, frontend):
    """`base`'s run with its threshold sweep, computed once for the tests that only read it (a run and its sweep
    of four back-end replays are this file's largest repeated cost)."""
    return run(base, frontend, sweep=threshold_sweep)


# Loose gates and threshold: many candidates, and verification accepts nearly anything it registers.
PERMISSIVE = {
    "similarity_threshold": 0.4,
    "min_travel_m": 0.0,
    "drift_check": "off",
    "verifier": {"max_residual": 10.0, "min_inliers": 1, "min_inlier_fraction": 0.0},
}


def test_optimisation_reduces_ate_when_loops_exist(swept):
    result = swept
    m = metrics_json(result)
    assert m["verified"] > 0 and m["false_loops"] == 0
    assert m["after"]["ate_translation_m"] < 0.3 * m["before"]["ate_translation_m"]
    assert m["improvement_pct"]["translation"] > 70 and m["improvement_pct"]["rotation"] > 50
    assert m["keyframes"] == len(result.keyframes) == len(result.optimised)
    # constant 3 m on ~2 m steps keeps roughly every other frame
    assert 0.3 * m["frames"] < m["keyframes"] < 0.7 * m["frames"]
    mem = m["memory_bytes"]
    assert mem["total"] == mem["keyframe_descriptors"] + mem["keyframe_clouds"] + mem["graph"] > 0
    assert set(m["time_s"]) >= {"sampling", "loop_detection", "verification", "optimisation", "backend_total"}
    assert 0 <= m["pr_auc"] <= 1 and 0 <= m["f1_max"] <= 1


def test_no_loops_means_no_correction(base, frontend):
    cfg = base.model_copy(update={"similarity_threshold": 1.0})
    m = metrics_json(run(cfg, frontend, sweep=threshold_sweep))
    assert m["verified"] == 0
    assert m["after"]["ate_translation_m"] == pytest.approx(m["before"]["ate_translation_m"], rel=1e-6)
    assert m["improvement_pct"]["translation"] == pytest.approx(0.0, abs=1e-4)


def test_oracle_mode_accepts_no_distant_loop(base, frontend):
    cfg = make_config({**base.dump(), **PERMISSIVE, "mode": "oracle"})
    result = run(cfg, frontend, sweep=threshold_sweep)
    far = [c for c in result.loops if c.gt_distance > cfg.loop_radius]
    assert far, "the permissive threshold should yield candidates that are not true loops"
    assert not any(c.verified for c in far)
    assert metrics_json(result)["loop_accounting"]["distant_loops"] == 0
    assert all(c.gt_distance <= cfg.loop_radius for c in result.accepted_loops)


def test_realistic_mode_counts_its_false_loops(base, frontend):
    cfg = make_config({**base.dump(), **PERMISSIVE, "mode": "realistic"})
    result = run(cfg, frontend)  # no sweep: at PERMISSIVE's threshold it would replay many times the candidates
    m = metrics_json(result)
    assert all(c.verified for c in result.loops)  # realistic: every candidate is registered
    far = [c for c in result.accepted_loops if c.gt_distance > cfg.loop_radius]
    assert m["loop_accounting"]["distant_loops"] == len(far) > 0
    # false: the measured pose is off; metrics.json, loops.csv and the figure's false loops are the same loops
    false = [c for c in result.accepted_loops if is_false_loop(c, result.gt_poses, cfg.loop_radius)]
    assert m["false_loops"] == len(false)
    flags = [r["false_loop"] for r in csv.DictReader(io.StringIO(loops_csv(result)))]
    assert flags.count("1") == len(false) and flags.count("0") == len(result.loops) - len(false)
    assert len(loop_edges(result)[1]) == len(false)
    assert m["verified"] == len(result.accepted_loops)
    assert m["candidates"] == len(result.loops) == m["registrations"]


def test_frontend_is_cached_and_checked(base, frontend):
    again = prepare_frontend(base)
    assert again.cached == {"odometry": True, "descriptors": True, "clouds": True}
    np.testing.assert_array_equal(again.descriptors, frontend.descriptors)
    np.testing.assert_array_equal(again.odometry, frontend.odometry)
    other = base.model_copy(update={"descriptor_params": {"n_sector": 30}})
    with pytest.raises(InputError, match="front end"):
        run(other, frontend, sweep=threshold_sweep)


def test_compare_writes_table(base, frontend, tmp_path):
    methods = (("constant-3m", "constant", {"distance": 3.0}), ("msa", "msa", {}))
    report = run_compare(base, tmp_path / "cmp", methods=methods)
    folder = report.parent
    assert report.is_file() and "| constant-3m |" in report.read_text()
    # peak RSS is one process figure: a single line, no per-method column; per-run reports say whose it is
    peak = [line for line in report.read_text().splitlines() if "peak rss" in line.lower()]
    assert len(peak) == 1 and peak[0].startswith("Process peak RSS: ") and "not a per-method figure" in peak[0]
    run_report = (folder / "runs" / "msa" / "report.md").read_text()
    assert "process peak RSS (whole process, not this method): " in run_report
    assert "RSS growth over this run's back-end: " in run_report
    # RSS growth is per method: a column of the table, next to the accounted memory
    metrics = json.loads((folder / "runs" / "msa" / "metrics.json").read_text())
    assert isinstance(metrics["rss_growth_bytes"], int)
    assert "| memory [MiB] | RSS growth [MiB] |" in report.read_text()
    assert "| memory (keyframes + graph) | back-end time |" in run_report
    lines = (folder / "comparison.csv").read_text().splitlines()
    assert lines[0].split(",") == list(COLUMNS) and len(lines) == 3
    assert {p.name for p in (folder / "runs").iterdir()} == {"constant-3m", "msa"}
    for name in ("metrics.png", "trajectories.png", "pr_curves.png"):
        assert (folder / "figures" / name).read_bytes()[:4] == b"\x89PNG"
    rows = list(csv.DictReader(open(folder / "comparison.csv")))
    # the same denominator for every sampler: full-rate "ATE before" is the odometry's, keyframe-only differs
    assert rows[0]["ate_before_m"] == rows[1]["ate_before_m"] != ""
    assert rows[0]["kf_ate_before_m"] != rows[1]["kf_ate_before_m"]
    pr = list(csv.DictReader(open(folder / "figures" / "pr.csv")))
    assert {(r["method"], r["protocol"]) for r in pr} == {
        (m, p) for m in ("constant-3m", "msa") for p in ("paper", "reference")
    }
    assert "| method | 0.70 | 0.75 | 0.80 | 0.85 |" in report.read_text()
    assert "| RPE 100-400 m [%] |" in (folder / "comparison.md").read_text() and "100-800" not in report.read_text()


def test_compare_without_sweep_says_it_was_not_run(base, frontend, tmp_path):
    report = run_compare(
        base, tmp_path / "cmp", methods=(("constant-3m", "constant", {"distance": 3.0}),), sweep=False, figures=False
    )
    text = report.read_text()
    assert "Threshold sensitivity: not run: left out with `--no-sweep`" in text
    assert "| method | 0.70 |" not in text
    metrics = json.loads((report.parent / "runs" / "constant-3m" / "metrics.json").read_text())
    assert metrics["threshold_sweep"] is None and metrics["time_s"]["threshold_sweep"] is None
    assert metrics["unavailable"]["threshold_sweep"].startswith("not run: left out with `--no-sweep`")


def test_compare_without_figures_writes_the_tables_and_data_files(base, frontend, tmp_path):
    methods = (("constant-3m", "constant", {"distance": 3.0}), ("all", "all", {}))
    folder = run_compare(base, tmp_path / "cmp", methods=methods, sweep=False, figures=False).parent
    assert not list(folder.rglob("*.png")) and "![" not in (folder / "report.md").read_text()
    assert {p.name for p in (folder / "figures").iterdir()} == {"pr.csv"}  # the curves' data, not drawn
    assert {r["method"] for r in csv.DictReader(open(folder / "figures" / "pr.csv"))} == {"constant-3m", "all"}
    for name, _, _ in methods:
        run = folder / "runs" / name
        assert not (run / "figures").exists() and "![" not in (run / "report.md").read_text()
        assert {"metrics.json", "frames.csv", "loops.csv", "pr.csv"} <= {p.name for p in run.iterdir()}


def test_full_rate_trajectory_is_written_and_evaluated(base, frontend, tmp_path):
    result = run(base, frontend)
    full = result.optimised_full
    assert full.shape == result.odometry.shape
    np.testing.assert_allclose(full[result.keyframes], result.optimised, atol=1e-9)
    m = metrics_json(result)["full_rate"]
    assert m["frames"] == len(result) and m["after"]["ate_translation_m"] < m["before"]["ate_translation_m"]
    assert metrics_json(result)["threshold_sweep"] is None
    folder = write_run(lambda: result, tmp_path / "out").parent
    # the ~400 m figure-eight has segments of 100-400 m only: the report must not claim KITTI's 100-800 m
    report = (folder / "report.md").read_text()
    assert "100-800" not in report and "| RPE translation [%], 100-400 m |" in report
    assert "segments of 100, 200, 300, 400 m only" in report
    np.testing.assert_allclose(read_poses(folder / "trajectories" / "optimised.kitti")[0], full, atol=1e-5)
    poses, stamps = read_poses(folder / "trajectories" / "optimised.tum")
    np.testing.assert_allclose(poses, full, atol=1e-5)
    np.testing.assert_allclose(stamps, result.times, atol=1e-6)


def test_threshold_sweep_replays_the_backend(base, frontend, swept):
    """The sweep's row at the run's own threshold is the run; lower thresholds accept at least as many loops
    (candidate sets are nested), and a replay at the run's threshold reproduces its loops and poses."""
    from msa_slam.experiments.sweep import replay
    from msa_slam.registration import KeyframeCloudStore

    result = swept
    sweep = metrics_json(result)["threshold_sweep"]
    assert [r["threshold"] for r in sweep] == [0.7, 0.75, 0.8, 0.85]
    assert sweep[2]["loops_accepted"] == metrics_json(result)["verified"]
    assert sweep[2]["improvement_t_pct"] == metrics_json(result)["full_rate"]["improvement_pct"]["translation"]
    accepted, candidates = [r["loops_accepted"] for r in sweep], [r["candidates"] for r in sweep]
    assert accepted == sorted(accepted, reverse=True)
    assert candidates == sorted(candidates, reverse=True) and candidates[0] > candidates[-1]
    clouds = KeyframeCloudStore(base.verifier.voxel_size)
    for k in result.keyframes:
        clouds.add(int(k), frontend.sequence[int(k)].points)
    again = replay(result.config, frontend, clouds, result.keyframes, {})
    assert [(c.query, c.match, c.accepted) for c in again.loops] == [
        (c.query, c.match, c.accepted) for c in result.loops
    ]
    np.testing.assert_allclose(again.optimised, result.optimised, atol=1e-9)


def test_reference_protocol_pr_is_na_without_enough_keyframes(base, frontend):
    """The reference protocol queries only once more than 10 keyframes precede a frame: with a sampler that
    keeps fewer, its PR is n/a with the reason."""
    result = run(make_config({**base.dump(), "sampler_params": {"distance": 40.0}}), frontend)
    assert metrics_json(result)["keyframes"] <= 11
    ref = metrics_json(result)["pr_reference"]
    assert ref == {"pr_auc": None, "f1_max": None, "matches": 0}
    assert "recorded no match" in metrics_json(result)["unavailable"]["pr_reference"]


def test_bad_inputs_fail_clearly(base, tmp_path):
    with pytest.raises(InputError, match="nowhere.*not found"):
        prepare_frontend(make_config(dataset=str(tmp_path / "nowhere")))
    with pytest.raises(InputError, match="unknown sampler 'fancy'.*msa"):  # when the config is built
        make_config({**base.dump(), "sampler": "fancy", "sampler_params": {}})
    with pytest.raises(InputError, match="unknown name 'nope'"):
        prepare_frontend(base.model_copy(update={"descriptor": "nope"}))
    with pytest.raises(InputError, match="unknown key 'thresold'; valid keys: .*similarity_threshold"):
        make_config(dataset="x", thresold=0.5)
    with pytest.raises(InputError, match="unknown key 'verifier.gate'; valid keys: .*max_residual"):
        make_config(dataset="x", verifier={"gate": 1})
    with pytest.raises(InputError, match="mode"):
        make_config(dataset="x", mode="psychic")
    with pytest.raises(InputError, match="lambda_z.*sampler 'msa'"):
        apply_params(make_config(dataset="x"), ["lambda_z=3"])
    with pytest.raises(InputError, match="unknown simulated sequence 'atlantis'"):
        prepare_frontend(make_config(dataset="sim:atlantis"))
    for empty in ("sim:", "sim: "):  # sim:$SEQUENCE with the variable unset: not the default (whole KITTI-05)
        with pytest.raises(InputError, match="names no simulated sequence; give sim:NAME"):
            prepare_frontend(make_config(dataset=empty))


def test_mismatched_pose_file_is_rejected(base, odometry_file, tmp_path):
    poses, _ = read_poses(odometry_file)
    short = tmp_path / "short.txt"
    write_poses(short, poses[:-5])
    with pytest.raises(InputError, match=rf"short.txt: {len(poses) - 5} poses but the run reads {len(poses)} scans"):
        prepare_frontend(base.model_copy(update={"odometry": str(short)}))
    with pytest.raises(InputError, match="neither 'kiss' nor an existing pose file"):
        prepare_frontend(base.model_copy(update={"odometry": str(tmp_path / "missing.txt")}))


def test_apply_params_routes_keys():
    cfg = apply_params(
        make_config(dataset="x"),
        [
            "lambda_u=5",
            "verifier.max_residual=0.2",
            "graph.robust=cauchy",
            "similarity_threshold=0.7",
            "odometry.max_range=80",
        ],
    )
    assert cfg.sampler_params == {"lambda_u": 5}
    assert cfg.verifier.max_residual == 0.2 and cfg.graph.robust == "cauchy"
    assert cfg.similarity_threshold == 0.7 and cfg.odometry_params == {"max_range": 80}


# either protocol (the verified one's drift pre-filter off: no odometry is given here)
@pytest.mark.parametrize("protocol", [{"loop_protocol": "paper"}, {"loop_protocol": "verified", "drift_check": "off"}])
def test_unregistrable_candidate_is_rejected_not_fatal(protocol):
    from msa_slam.descriptors import ScanContext
    from msa_slam.registration import KeyframeCloudStore, Verifier
    from msa_slam.slam import KeyframeStore, LoopCloser, LoopClosure

    store = KeyframeStore(ScanContext(), KeyframeCloudStore(0.5))
    rng = np.random.default_rng(0)
    for k, points in enumerate((rng.uniform(-20, 20, (5000, 3)), rng.uniform(-1, 1, (4, 3)))):  # 4: too sparse
        store.add_cloud(k, points)
        store.add(k, np.eye(4), np.zeros((20, 60)))
    out = LoopCloser(store, Verifier(), make_config(dataset="x", mode="realistic", **protocol)).verify(
        [LoopClosure(1, 0, 0.9, 1.0)]
    )
    assert out[0].verified and not out[0].accepted and out[0].residual == float("inf") and out[0].rejected == "sparse"


def _posed_sequence(folder: Path, sequence: Path, gt: np.ndarray, odometry: np.ndarray) -> tuple[Path, Path]:
    """The first len(gt) scans of `sequence` (linked) with ground truth `gt`, and an odometry pose file."""
    (folder / "velodyne").mkdir(parents=True)
    for i in range(len(gt)):
        (folder / "velodyne" / f"{i:06d}.bin").symlink_to(sequence / "velodyne" / f"{i:06d}.bin")
    times = (sequence / "times.txt").read_text().splitlines()[: len(gt)]
    (folder / "times.txt").write_text("\n".join(times) + "\n")
    shutil.copy(sequence / "calib.txt", folder / "calib.txt")  # Tr = identity: poses are LiDAR poses
    write_poses(folder / "poses.txt", gt)
    write_poses(folder / "odometry.txt", odometry)
    return folder, folder / "odometry.txt"


def _spin(n: int) -> np.ndarray:
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("z", np.linspace(0, 2 * np.pi, n)[:, None]).as_matrix()
    return poses


def test_rotation_only_run_reports_ate_na_through_the_cli(sequence, cache_dir, tmp_path):
    gt = _spin(30)
    dataset, odometry = _posed_sequence(tmp_path / "spin", sequence, gt, drifted(gt, yaw_per_frame=0.01))
    out = tmp_path / "run"
    result = CliRunner().invoke(
        app,
        [
            "run",
            "--dataset",
            str(dataset),
            "--odometry",
            str(odometry),
            "--sampler",
            "all",
            "--cache-dir",
            str(cache_dir),
            "--out",
            str(out),
            "--quiet",
        ],
    )
    assert result.exit_code == 0, result.output
    m = json.loads((out / "metrics.json").read_text())
    assert m["before"]["ate_translation_m"] is None and m["after"]["ate_rotation_deg"] is None
    assert m["improvement_pct"] == {"translation": None, "rotation": None}
    assert m["unavailable"]["ate"].startswith("SE(3) alignment undetermined")
    assert m["before"]["rpe_rotation_deg"] == pytest.approx(np.degrees(0.01), rel=1e-3)  # RPE needs no alignment
    rows = [r for r in csv.DictReader((out / "frames.csv").open()) if r["is_keyframe"] == "1"]
    assert len(rows) == 30 and {(r["ate_odom_m"], r["ate_opt_m"]) for r in rows} == {("n/a", "n/a")}
    report = (out / "report.md").read_text()
    assert "| ATE translation [m], keyframes only | n/a | n/a | n/a |" in report
    assert "| ATE translation [m], full rate | n/a | n/a | n/a |" in report
    assert f"- ATE (and its % improvement) n/a: {m['unavailable']['ate']}" in report
    assert (out / "figures" / "trajectories.png").is_file()


def test_stationary_run_gives_ate_none(sequence, cache_dir, tmp_path):
    gt = np.tile(np.eye(4), (30, 1, 1))
    dataset, odometry = _posed_sequence(tmp_path / "still", sequence, gt, gt)
    cfg = make_config(dataset=str(dataset), odometry=str(odometry), cache_dir=str(cache_dir), sampler="all")
    m = metrics_json(run(cfg, sweep=threshold_sweep))
    assert m["before"]["ate_translation_m"] is None and "point or a line" in m["unavailable"]["ate"]


def test_short_straight_run_warns_and_has_no_pr(sequence, cache_dir, tmp_path):
    n = 30
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 0, 3] = np.arange(n) * 1.0
    gt[:, 1, 3] = 0.05 * np.sin(np.arange(n))
    dataset, odometry = _posed_sequence(tmp_path / "straight", sequence, gt, drifted(gt))
    cfg = make_config(
        dataset=str(dataset),
        odometry=str(odometry),
        cache_dir=str(cache_dir),
        sampler="all",
        min_frame_gap=5,
        exclude_recent=2,
        min_travel_m=5.0,
    )
    result = run(cfg, sweep=threshold_sweep)
    m = metrics_json(result)
    assert m["before"]["ate_rotation_deg"] is not None and m["ate_rotation_reliable"] is False
    assert len(m["warnings"]) == 1 and "rotation ATE unreliable" in m["warnings"][0]
    assert "nearly straight" in m["warnings"][0]
    assert m["ate_alignment"].startswith("SE(3) Umeyama (rotation + translation, no scale)")
    assert m["pr_queries"] > 0 and m["pr_auc"] is None and m["f1_max"] is None
    assert "no revisit" in m["unavailable"]["pr"]
    report = write_run(lambda: result, tmp_path / "out").read_text()
    assert "| ATE rotation [deg] (unreliable: see notes), keyframes only |" in report and "| n/a / n/a |" in report
    assert f"- warning: {m['warnings'][0]}" in report and f"- PR-AUC / F1-max n/a: {m['unavailable']['pr']}" in report
    assert f"of the keyframe rows: {m['ate_alignment']} (`evo_ape tum" in report
    assert (
        f"ATE alignment of the full-rate rows: {m['full_rate']['ate_alignment']} (`evo_ape tum trajectories/gt.tum "
        "trajectories/optimised.tum -a`"
    ) in report and "on all" in m["full_rate"]["ate_alignment"]


def _improvement(translation: float, rotation: float):
    """An edit of metrics.json setting both % improvements (keyframes and full rate)."""

    def change(m: dict) -> None:
        m["improvement_pct"] = {"translation": translation, "rotation": rotation}
        m["full_rate"]["improvement_pct"] = {"translation": translation, "rotation": rotation}

    return change


def test_improvement_rounding_to_zero_prints_unsigned(swept, tmp_path):
    result = edited(swept, _improvement(-0.04, -0.0004))
    report = write_run(lambda: result, tmp_path / "out").read_text()
    ate_rows = [line for line in report.splitlines() if line.startswith("| ATE ")]
    assert "-0.0" not in report and sum(line.endswith(" 0.0 % |") for line in ate_rows) == 4  # full rate, keyframes
    result = edited(result, _improvement(-0.0004, -0.0001))
    table = table_markdown([table_row(result.metrics)])
    assert "-0.0" not in table and "| 0.0 | 0.0 |" in table


def _decimals(cell: str) -> int | None:
    return len(cell.split(".")[1]) if "." in cell else None


def test_comparison_table_columns_keep_one_number_of_decimals():
    """A column never mixes 0.123 and 12.3 (values either side of 10 used to switch from 3 to 1 decimal)."""
    small = {c: 0.5 + i for i, c in enumerate(COLUMNS[1:])}
    rows = [
        ComparisonRow("a", {**small, "keyframes": 7}),
        ComparisonRow("b", {**{c: 12.5 + 10 * i for i, c in enumerate(COLUMNS[1:])}, "keyframes": 70}),
    ]
    lines = table_markdown(rows).splitlines()
    header = [h.strip() for h in lines[0].strip("|").split("|")]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines[2:]]
    decimals = {h: {_decimals(row[i]) for row in cells} for i, h in enumerate(header)}
    assert all(len(d) == 1 for d in decimals.values()), decimals
    assert decimals["ATE after [m]"] == {3} and decimals["t. ATE impr. [%]"] == {1}
    assert decimals["memory [MiB]"] == decimals["time [s]"] == {2} and decimals["keyframes"] == {None}


@pytest.mark.parametrize(
    "length, span, said",
    [
        (250.0, "100-200 m", "segments of 100, 200 m only (the trajectory of 250.0 m is too short"),
        (850.0, "100-800 m", "RPE over KITTI's 100-800 m segments"),
        (50.0, "KITTI segments", "n/a: the trajectory of 50.0 m is shorter than the segment lengths (100-800 m)"),
    ],
)
def test_rpe_segments_name_the_lengths_evaluated(length, span, said):
    from msa_slam.reporting.sequence_text import rpe_segments

    gt = np.tile(np.eye(4), (201, 1, 1))
    gt[:, 0, 3] = np.linspace(0, length, 201)
    assert rpe_segments(gt)[0] == span and said in rpe_segments(gt)[1]
    assert "n/a" in rpe_segments(None)[1]
