"""The result files a researcher uses outside msa-slam: full-rate ground truth, the map as PLY,
the pose graph as g2o, the PR arrays, the run's descriptors (reusable by `msa-slam sample`), provenance, and
a documented metrics.json."""

from __future__ import annotations

import csv
import json
import re
from importlib import metadata
from pathlib import Path

import gtsam
import numpy as np
import pytest
import trimesh
from helpers.results import stable_content
from scipy.integrate import trapezoid
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.io.ply import write_ply
from msa_slam.io.poses import read_poses

runner = CliRunner()
DOCS = Path(__file__).resolve().parents[1] / "docs" / "metrics.md"


def _run(command: str, sequence, odometry_file, cache_dir, out: Path) -> Path:
    result = runner.invoke(
        app,
        [
            command,
            "--dataset",
            str(sequence),
            "--odometry",
            str(odometry_file),
            "--descriptor",
            "sc",
            "--mode",
            "oracle",
            "--cache-dir",
            str(cache_dir),
            "--out",
            str(out),
            "--quiet",
        ],
    )
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def batch(sequence, odometry_file, cache_dir, tmp_path_factory) -> Path:
    return _run("run", sequence, odometry_file, cache_dir, tmp_path_factory.mktemp("files") / "run")


@pytest.fixture(scope="module")
def online(sequence, odometry_file, cache_dir, tmp_path_factory) -> Path:
    return _run("online", sequence, odometry_file, cache_dir, tmp_path_factory.mktemp("files") / "online")


def _metrics(folder: Path) -> dict:
    return json.loads((folder / "metrics.json").read_text())


def test_full_rate_ground_truth_matches_the_sequence_with_the_frames_times(batch, sequence):
    gt, _ = read_poses(sequence / "poses.txt")
    kitti, _ = read_poses(batch / "trajectories" / "gt.kitti", "kitti")
    tum, times = read_poses(batch / "trajectories" / "gt.tum", "tum")
    np.testing.assert_allclose(kitti, gt, atol=1e-6)
    np.testing.assert_allclose(tum[:, :3, 3], gt[:, :3, 3], atol=1e-6)
    _, odometry_times = read_poses(batch / "trajectories" / "odometry.tum", "tum")
    np.testing.assert_array_equal(times, odometry_times)  # evo pairs the full-rate files frame by frame
    optimised, optimised_times = read_poses(batch / "trajectories" / "optimised.tum", "tum")
    np.testing.assert_array_equal(optimised_times, times)
    assert np.all(np.diff(times) > 0)


@pytest.mark.parametrize("count", [0, 1, 500])
def test_write_ply_gives_float32_vertices_other_readers_open(tmp_path, count):
    points = np.random.default_rng(count).normal(size=(count, 4)) * 50  # a fourth column (intensity) is left out
    write_ply(tmp_path / "map.ply", points)
    raw = (tmp_path / "map.ply").read_bytes()
    header = (
        b"ply\nformat binary_little_endian 1.0\ncomment written by msa-slam\nelement vertex %d\n"
        b"property float x\nproperty float y\nproperty float z\nend_header\n" % count
    )
    assert raw.startswith(header)
    np.testing.assert_array_equal(
        np.frombuffer(raw[len(header) :], "<f4").reshape(-1, 3), points[:, :3].astype(np.float32)
    )
    if count:
        np.testing.assert_array_equal(
            np.asarray(trimesh.load(tmp_path / "map.ply").vertices, np.float32), points[:, :3].astype(np.float32)
        )


def test_map_ply_holds_the_keyframe_clouds_at_their_optimised_poses(batch):
    cloud = trimesh.load(batch / "map.ply")
    points = np.asarray(cloud.vertices)
    assert len(points) > 1000
    header = (batch / "map.ply").read_bytes()[:80]
    assert header.startswith(b"ply\nformat binary_little_endian 1.0\n")
    optimised, _ = read_poses(batch / "trajectories" / "optimised_keyframes.kitti", "kitti")
    centres = optimised[:, :3, 3]
    # Every map point is within the sensor's reach of some keyframe, and the map spans the whole path.
    nearest = np.min(np.linalg.norm(points[::50, None, :] - centres[None], axis=2), axis=1)
    assert nearest.max() < 120.0
    lo, hi = points.min(axis=0), points.max(axis=0)
    assert np.all(lo[:2] <= centres[:, :2].min(axis=0)) and np.all(hi[:2] >= centres[:, :2].max(axis=0))
    voxels = np.unique(np.floor(points / 0.5).astype(np.int64), axis=0)
    assert len(voxels) > 0.5 * len(points)  # voxel-downsampled, not the raw scans stacked


def test_pose_graph_g2o_reads_back_into_gtsam_at_its_optimum(batch):
    metrics = _metrics(batch)
    graph, values = gtsam.readG2o(str(batch / "pose_graph.g2o"), True)
    assert values.size() == metrics["keyframes"]
    assert graph.size() == metrics["keyframes"] - 1 + metrics["verified"]
    optimised, _ = read_poses(batch / "trajectories" / "optimised_keyframes.kitti", "kitti")
    keys = metrics["keyframe_frames"]
    np.testing.assert_allclose(np.stack([values.atPose3(k).matrix() for k in keys]), optimised, atol=1e-6)
    # With the information in the file, the written poses are the optimum: re-optimising moves nothing.
    graph.add(gtsam.PriorFactorPose3(keys[0], values.atPose3(keys[0]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    again = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    moved = [np.linalg.norm(again.atPose3(k).translation() - values.atPose3(k).translation()) for k in keys]
    assert max(moved) < 1e-3
    text = (batch / "pose_graph.g2o").read_text()
    assert re.search(r"^FIX 0$", text, re.M) and "-0.000000000" not in text


def test_g2o_names_a_robust_loop_kernel_and_keeps_each_factors_information():
    from msa_slam.backend import PoseGraph
    from msa_slam.backend.graph_config import GraphConfig
    from msa_slam.io.g2o import format_g2o

    graph = PoseGraph(GraphConfig(robust="cauchy"), mode="realistic")
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, 0, 3] = [0.0, 1.0, 2.0]
    for k, pose in enumerate(poses):
        graph.add_keyframe(k, pose)
    covariance = np.diag([1e-4, 2e-4, 3e-4, 0.01, 0.02, 0.03])  # GTSAM order: rotation, translation
    graph.add_loop(0, 2, np.linalg.inv(poses[0]) @ poses[2], covariance)
    text = format_g2o([0, 1, 2], poses, graph.factors)
    lines = text.splitlines()
    assert lines[0].startswith("#") and "cauchy" in lines[0]
    loop = [ln for ln in lines if ln.startswith("EDGE_SE3:QUAT 0 2 ")]
    info = np.array(loop[0].split()[10:], dtype=float)
    g2o_order = [3, 4, 5, 0, 1, 2]  # translation first
    expected = np.linalg.inv(covariance)[np.ix_(g2o_order, g2o_order)][np.triu_indices(6)]
    np.testing.assert_allclose(info, expected, rtol=1e-6)


def test_pr_csv_holds_the_curve_behind_pr_auc(batch):
    metrics = _metrics(batch)
    rows = list(csv.DictReader((batch / "pr.csv").open()))
    assert [r["threshold"] for r in rows[:3]] == ["0.00", "0.01", "0.02"] and len(rows) == 100
    precision = np.array([float(r["precision"]) for r in rows])
    recall = np.array([float(r["recall"]) for r in rows])
    assert metrics["pr_auc"] is not None
    assert abs(abs(trapezoid(precision, recall)) - metrics["pr_auc"]) < 1e-4
    assert max(float(r["f1"]) for r in rows) == pytest.approx(metrics["f1_max"], abs=1e-5)


def test_descriptors_npy_lets_sample_reproduce_the_runs_keyframes(batch, tmp_path):
    metrics = _metrics(batch)
    descriptors = np.load(batch / "descriptors.npy")
    assert len(descriptors) == metrics["frames"]
    args = [
        "sample",
        "--poses",
        str(batch / "trajectories" / "odometry.kitti"),
        "--descriptors",
        str(batch / "descriptors.npy"),
        "--sampler",
        metrics["sampler"],
        "--out",
        str(tmp_path / "s"),
        "--quiet",
    ]
    if metrics["sampler_stats"]["flushed_keyframes"]:
        args.append("--flush")
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    keyframes = [int(x) for x in (tmp_path / "s" / "keyframes.txt").read_text().split()]
    assert keyframes == metrics["keyframe_frames"]


def test_provenance_records_versions_command_date_and_cpu(batch):
    record = json.loads((batch / "provenance.json").read_text())
    assert record["msa_slam_version"] == _metrics(batch)["msa_slam_version"]
    assert record["libraries"]["numpy"] == metadata.version("numpy")
    assert record["libraries"]["gtsam"] == metadata.version("gtsam")
    assert isinstance(record["command_line"], list) and record["cpu_model"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", record["date_utc"])


def test_online_run_writes_map_graph_and_pr_but_no_descriptors(online):
    metrics = _metrics(online)
    for name in ("map.ply", "pose_graph.g2o", "pr.csv", "provenance.json", "trajectories/gt.tum"):
        assert (online / name).is_file(), name
    assert not (online / "descriptors.npy").exists()  # online keeps no per-frame descriptor history
    _, values = gtsam.readG2o(str(online / "pose_graph.g2o"), True)
    assert values.size() == metrics["keyframes"]


def test_new_files_are_identical_between_two_runs(batch, sequence, odometry_file, cache_dir, tmp_path):
    again = stable_content(_run("run", sequence, odometry_file, cache_dir, tmp_path / "again"))
    first = stable_content(batch)
    for name in ("map.ply", "pose_graph.g2o", "pr.csv", "descriptors.npy", "trajectories/gt.tum"):
        assert first[name] == again[name], name
    assert "provenance.json" not in first  # volatile: date and command line


def _keys(value, prefix: str = "") -> set[str]:
    """Dotted keys of metrics.json, down to the fixed structure (not free-form maps or lists)."""
    free = {"sampler_stats", "odometry_config", "unavailable", "latency_ms", "frontend_time_s", "time_s"}
    out = set()
    for key, item in value.items():
        out.add(key)
        if isinstance(item, dict) and key not in free:
            out |= _keys(item)
    return out


def test_every_metrics_key_is_explained_in_docs(batch, online):
    text = DOCS.read_text()
    documented = set(re.findall(r"`([A-Za-z0-9_]+)`", text))
    missing = (_keys(_metrics(batch)) | _keys(_metrics(online))) - documented
    assert not missing, f"keys of metrics.json not explained in docs/metrics.md: {sorted(missing)}"
    report = (batch / "report.md").read_text()
    assert "ATE alignment of the full-rate rows: SE(3)" in report and "docs/metrics.md" in report
