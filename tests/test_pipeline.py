"""Batch pipeline on the small simulated figure-eight (msa_slam.sim's "test" sequence).

Odometry is the ground truth with a constant yaw bias and 1 % scale error (a pose file; fixtures in
conftest.py), so the tests need no KISS-ICP and the drift is known: loops at the crossing must pull the
trajectory back.
"""

from __future__ import annotations

import numpy as np
import pytest

from msa_slam.errors import InputError
from msa_slam.io.poses import read_poses, write_poses
from msa_slam.pipeline import apply_params, make_config, prepare_frontend, run_batch
from msa_slam.pipeline.compare import COLUMNS, run_compare


@pytest.fixture(scope="session")
def base(sequence, odometry_file, cache_dir):
    return make_config(dataset=str(sequence), odometry=str(odometry_file), cache_dir=str(cache_dir),
                       sampler="constant", sampler_params={"distance": 3.0})


@pytest.fixture(scope="session")
def frontend(base):
    return prepare_frontend(base)


# Loose gates and threshold: many candidates, and verification accepts nearly anything it registers.
PERMISSIVE = {"similarity_threshold": 0.4,
              "verifier": {"max_residual": 10.0, "min_inliers": 1, "min_inlier_fraction": 0.0}}


def test_optimisation_reduces_ate_when_loops_exist(base, frontend):
    result = run_batch(base, frontend)
    m = result.metrics
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
    m = run_batch(cfg, frontend).metrics
    assert m["verified"] == 0
    assert m["after"]["ate_translation_m"] == pytest.approx(m["before"]["ate_translation_m"], rel=1e-6)
    assert m["improvement_pct"]["translation"] == pytest.approx(0.0, abs=1e-4)


def test_oracle_mode_adds_no_false_loop(base, frontend):
    cfg = make_config({**base.dump(), **PERMISSIVE, "mode": "oracle"})
    result = run_batch(cfg, frontend)
    far = [c for c in result.loops if c.gt_distance > cfg.loop_radius]
    assert far, "the permissive threshold should yield candidates that are not true loops"
    assert not any(c.verified for c in far)
    assert result.metrics["false_loops"] == 0
    assert all(c.gt_distance <= cfg.loop_radius for c in result.accepted_loops)


def test_realistic_mode_counts_its_false_loops(base, frontend):
    cfg = make_config({**base.dump(), **PERMISSIVE, "mode": "realistic"})
    result = run_batch(cfg, frontend)
    m = result.metrics
    assert all(c.verified for c in result.loops)  # realistic: every candidate is registered
    false = [c for c in result.accepted_loops if c.gt_distance > cfg.loop_radius]
    assert m["false_loops"] == len(false) > 0
    assert m["verified"] == len(result.accepted_loops)
    assert m["candidates"] == len(result.loops) == m["registrations"]


def test_frontend_is_cached_and_checked(base, frontend):
    again = prepare_frontend(base)
    assert again.cached == {"odometry": True, "descriptors": True}
    np.testing.assert_array_equal(again.descriptors, frontend.descriptors)
    np.testing.assert_array_equal(again.odometry, frontend.odometry)
    other = base.model_copy(update={"descriptor_params": {"n_sector": 30}})
    with pytest.raises(InputError, match="front end"):
        run_batch(other, frontend)


def test_compare_writes_table(base, frontend, tmp_path):
    methods = (("constant-3m", "constant", {"distance": 3.0}), ("msa", "msa", {}))
    report = run_compare(base, tmp_path / "cmp", methods=methods)
    folder = report.parent
    assert report.is_file() and "| constant-3m |" in report.read_text()
    lines = (folder / "comparison.csv").read_text().splitlines()
    assert lines[0].split(",") == list(COLUMNS) and len(lines) == 3
    assert {p.name for p in (folder / "runs").iterdir()} == {"constant-3m", "msa"}
    for name in ("metrics.png", "trajectories.png", "pr_curves.png"):
        assert (folder / "figures" / name).read_bytes()[:4] == b"\x89PNG"


def test_bad_inputs_fail_clearly(base, tmp_path):
    with pytest.raises(InputError, match="nowhere.*not found"):
        prepare_frontend(make_config(dataset=str(tmp_path / "nowhere")))
    with pytest.raises(InputError, match="unknown sampler 'fancy'.*msa"):
        run_batch(base.model_copy(update={"sampler": "fancy", "sampler_params": {}}))
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


def test_mismatched_pose_file_is_rejected(base, odometry_file, tmp_path):
    poses, _ = read_poses(odometry_file)
    short = tmp_path / "short.txt"
    write_poses(short, poses[:-5])
    with pytest.raises(InputError, match=rf"short.txt: {len(poses) - 5} poses but the sequence has {len(poses)}"):
        prepare_frontend(base.model_copy(update={"odometry": str(short)}))
    with pytest.raises(InputError, match="neither 'kiss' nor an existing pose file"):
        prepare_frontend(base.model_copy(update={"odometry": str(tmp_path / "missing.txt")}))


def test_apply_params_routes_keys():
    cfg = apply_params(make_config(dataset="x"), ["lambda_u=5", "verifier.max_residual=0.2", "graph.robust=cauchy",
                                                   "similarity_threshold=0.7", "odometry.max_range=80"])
    assert cfg.sampler_params == {"lambda_u": 5}
    assert cfg.verifier.max_residual == 0.2 and cfg.graph.robust == "cauchy"
    assert cfg.similarity_threshold == 0.7 and cfg.odometry_params == {"max_range": 80}


def test_unregistrable_candidate_is_rejected_not_fatal():
    from msa_slam.descriptors import ScanContext
    from msa_slam.pipeline.loops import LoopCandidate, verify_candidates
    from msa_slam.registration import KeyframeCloudStore, Verifier

    clouds = KeyframeCloudStore(0.5)
    rng = np.random.default_rng(0)
    clouds.add(0, rng.uniform(-20, 20, (5000, 3)))
    clouds.add(1, rng.uniform(-1, 1, (4, 3)))  # a handful of points: too sparse to register
    descriptors = np.zeros((2, 20, 60))
    out = verify_candidates([LoopCandidate(1, 0, 0.9, 1.0)], clouds, Verifier(), ScanContext(), descriptors,
                            "realistic", 3.0)
    assert out[0].verified and not out[0].accepted and out[0].residual == float("inf")
