"""MSA's kernels compiled ahead (sampling/msa/warm.py), and a cold KISS-ICP front end starting that with the MSA
settings of the run."""

import pytest
from helpers.streams import write_scans

import msa_slam.pipeline.frontend as frontend
from msa_slam.odometry.cache import OdometryCache
from msa_slam.pipeline.config import make_config
from msa_slam.sampling.msa import exact, powerset, warm
from msa_slam.sampling.msa.warm import compile_kernels


def test_compile_kernels_compiles_what_the_default_mode_runs():
    compile_kernels({}, (20, 60))
    assert exact._gradient.signatures and powerset.feasible_subsets.signatures


@pytest.fixture(scope="module")
def long_scans(tmp_path_factory):
    return write_scans(tmp_path_factory.mktemp("long") / "scans", frontend.COMPILE_ALONGSIDE_FRAMES)


def _compiles(monkeypatch, tmp_path, scans, samplers: dict[str, dict], cached: bool = False) -> list:
    """What _compile_msa_alongside starts for methods `samplers` (name: params) on `scans` with an empty cache
    (or one holding the odometry when `cached`)."""
    started: list = []
    monkeypatch.setattr(frontend, "compile_in_background", lambda params, shape: started.append((params, shape)))
    configs = [
        make_config(
            dataset=str(scans), sampler=name, sampler_params=params, mode="realistic", cache_dir=str(tmp_path / "cache")
        )
        for name, params in samplers.items()
    ]
    plan = frontend.plan_frontend(configs[0])
    if cached:
        path = OdometryCache(plan.cache).path(OdometryCache.key(plan.sequence, plan.odometry.config, (), plan.cache))
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"")
    frontend._compile_msa_alongside(configs, plan)
    return started


def test_a_cold_kiss_icp_front_end_compiles_msa_with_the_runs_settings(monkeypatch, tmp_path, long_scans):
    methods = {"constant": {}, "msa": {"window": 12}}
    assert _compiles(monkeypatch, tmp_path, long_scans, methods) == [({"window": 12}, (20, 60))]


def test_no_compile_alongside_without_msa_with_cached_odometry_or_a_short_sequence(monkeypatch, tmp_path, long_scans):
    assert _compiles(monkeypatch, tmp_path, long_scans, {"constant": {}}) == []
    assert _compiles(monkeypatch, tmp_path, long_scans, {"msa": {}}, cached=True) == []
    short = write_scans(tmp_path / "short", frontend.COMPILE_ALONGSIDE_FRAMES - 1)
    assert _compiles(monkeypatch, tmp_path, short, {"msa": {}}) == []


def test_load_kernels_runs_each_setting_once_per_process(monkeypatch):
    runs = []
    monkeypatch.setattr(warm, "_LOADED", set())
    monkeypatch.setattr(warm, "compile_kernels", lambda params, shape: runs.append((params, shape)))
    warm.load_kernels("msa", {"window": 12, "mode": "exact"}, (256,))
    warm.load_kernels("msa", {"mode": "exact", "window": 12}, [256])  # the same settings in another order
    warm.load_kernels("msa", {"window": 12, "mode": "fast"}, (256,))
    warm.load_kernels("msa", {"window": 12, "mode": "fast"}, (20, 60))
    warm.load_kernels("constant", {"distance": 2.0}, (256,))
    assert runs == [
        ({"window": 12, "mode": "exact"}, (256,)),
        ({"window": 12, "mode": "fast"}, (256,)),
        ({"window": 12, "mode": "fast"}, (20, 60)),
    ]


def test_a_daemonic_worker_starts_no_compile_process(monkeypatch):
    monkeypatch.setattr(warm.multiprocessing.current_process(), "daemon", True)
    assert warm.compile_in_background({}, (20, 60)) is None
