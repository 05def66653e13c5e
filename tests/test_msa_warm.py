"""MSA's kernels compiled ahead (sampling/msa/warm.py) and the demo starting that with its own MSA settings."""

from pathlib import Path

import msa_slam.demo as demo
from msa_slam.sampling.msa import exact, powerset, warm
from msa_slam.sampling.msa.warm import compile_kernels


def test_compile_kernels_compiles_what_the_default_mode_runs():
    compile_kernels({}, (20, 60))
    assert exact._gradient.signatures and powerset.feasible_subsets.signatures


def test_demo_compiles_with_the_comparisons_msa_settings_and_descriptor_shape(monkeypatch, tmp_path):
    started = []
    monkeypatch.setattr(demo, "compile_in_background", lambda params, shape: started.append((params, shape)))
    monkeypatch.setattr(demo, "run_compare", lambda *args, **kwargs: tmp_path / "report.md")
    assert demo.run_demo(tmp_path / "out", cache_dir=tmp_path, quiet=True) == Path(tmp_path / "report.md")
    assert started == [({}, (20, 60))]


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
