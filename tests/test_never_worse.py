"""The fair evaluation's safety criterion on a short sequence with revisits: pose-graph optimisation never makes the
full-rate ATE worse than odometry by more than 5 %, for any of the paper's samplers, in oracle and in
realistic mode, and "ATE before" is the same number for every sampler."""

from __future__ import annotations

import pytest
from helpers.metrics import metrics_json

from msa_slam.experiments.compare import method_configs
from msa_slam.pipeline import make_config, prepare_frontend, run

MAX_WORSENING = 0.05  # the bound, relative to the odometry's full-rate ATE
# Rotation ATE on sim:test is ~0.1 deg; below this absolute change it is registration noise, not a regression.
ROTATION_RESOLUTION_DEG = 0.01


@pytest.fixture(scope="module")
def frontend(cache_dir):
    return prepare_frontend(make_config(dataset="sim:test", cache_dir=str(cache_dir)))


@pytest.mark.parametrize("mode", ["oracle", "realistic"])
def test_optimisation_never_worse_than_odometry(frontend, cache_dir, mode):
    base = make_config(dataset="sim:test", cache_dir=str(cache_dir), mode=mode)
    before, failures = set(), []
    for cfg in method_configs(base):
        m = metrics_json(run(cfg, frontend))
        full = m["full_rate"]
        assert m["verified"] > 0, f"{cfg.name}: no loop closed, the run does not exercise the optimisation"
        t0, t1 = full["before"]["ate_translation_m"], full["after"]["ate_translation_m"]
        r0, r1 = full["before"]["ate_rotation_deg"], full["after"]["ate_rotation_deg"]
        before.add((t0, r0))
        if t1 > (1 + MAX_WORSENING) * t0:
            failures.append(f"{cfg.name}: translation ATE {t0:.4f} -> {t1:.4f} m")
        if r1 > (1 + MAX_WORSENING) * r0 + ROTATION_RESOLUTION_DEG:
            failures.append(f"{cfg.name}: rotation ATE {r0:.4f} -> {r1:.4f} deg")
    assert not failures, f"{mode}: optimisation made the full-rate ATE worse: " + "; ".join(failures)
    assert len(before) == 1, f"ATE before differs between samplers: {before}"
