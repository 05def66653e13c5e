"""MSA's kernels compiled ahead (sampling/msa/warm.py) and the demo starting that with its own MSA settings."""

from pathlib import Path

import msa_slam.demo as demo
from msa_slam.sampling.msa import exact, powerset
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
