"""The reference's parity vectors (../shared/parity/stream_*.npz): loading them, naming their samplers, and a
module-scoped fixture with one stream per parameter."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from conftest import SHARED_DIR, shared_path

from msa_slam.sampling import make_sampler

MSA_NAME = re.compile(r"msa_N(\d+)_nn(\d+)_a([\d.]+)_b([\d.]+)_l([\d.]+)_u([\d.]+)$")
STREAMS = sorted((SHARED_DIR / "parity").glob("stream_*.npz")) if SHARED_DIR.exists() else []


def sampler_for(config: str, mode: str = "exact", pi: str = "reference"):
    """Translate a parity configuration name into one of our samplers."""
    match = MSA_NAME.match(config)
    if match:
        n, nb, a, b, lo, hi = match.groups()
        return make_sampler(
            "msa",
            window=int(n),
            neighbours=int(nb),
            alpha=float(a),
            beta=float(b),
            lambda_l=float(lo),
            lambda_u=float(hi),
            mode=mode,
            pi=pi,
        )
    if config == "fixed_0":
        return make_sampler("all")
    if config.startswith("fixed_"):
        return make_sampler("constant", distance=float(config[len("fixed_") :]))
    if config == "entropy_t0.05_d5":
        return make_sampler("entropy", threshold=0.05, max_distance=5.0)
    if config == "spaciousness_paper":
        return make_sampler("spaciousness")
    raise KeyError(config)


def load_stream(path):
    """(poses, descriptors, clouds, {configuration: expected keyframes}) of one parity vector."""
    data = np.load(path)
    return data["poses"], data["descriptors"], data["clouds"], json.loads(str(data["expected"]))


@pytest.fixture(scope="module", params=[p.name for p in STREAMS] or ["missing"])
def stream(request):
    """(file name, *load_stream) of each parity vector; skips when ../shared/parity is absent."""
    if request.param == "missing":
        pytest.skip("parity vectors not available (../shared/parity)")
    return (request.param, *load_stream(shared_path("parity", request.param)))
