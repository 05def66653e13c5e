"""Shared test helpers: locate ../shared (skip clearly when absent); the simulated sequences the tests run on."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msa_slam.io.poses import read_poses, write_poses
from msa_slam.sim import DEFAULT_CONFIGS, simulate_sequence
from msa_slam.sources import resolve_dataset

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DIR = REPO_ROOT.parent / "shared"


@pytest.hookimpl(trylast=True)  # after the terminal reporter is set up
def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist (`make test`), compile the numba kernels once in the controller before its workers start,
    instead of once in each worker on a fresh clone (helpers/kernels.py)."""
    if hasattr(config, "workerinput") or (config.getoption("numprocesses", 0) or 0) < 2 or config.option.collectonly:
        return
    from helpers.kernels import compile_test_kernels

    reporter = config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.write_line("compiling the numba kernels once for the workers (on a fresh clone: a minute or two)")
    compile_test_kernels()


def shared_path(*parts: str) -> Path:
    """Path inside ../shared; skips the calling test with a clear reason when it is missing."""
    path = SHARED_DIR.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"shared data not available: {path} (needs the project's ../shared folder)")
    return path


@pytest.fixture
def shared() -> callable:
    return shared_path


# Small simulated sequence shared by the pipeline tests (simulated once per session).


def drifted(gt: np.ndarray, yaw_per_frame: float = 0.002, scale: float = 1.01) -> np.ndarray:
    """Odometry with a known drift: every relative motion scaled and followed by a small yaw."""
    rel = np.linalg.inv(gt[:-1]) @ gt[1:]
    bias = np.eye(4)
    bias[:3, :3] = Rotation.from_euler("z", yaw_per_frame).as_matrix()
    out = [gt[0]]
    for motion in rel:
        step = motion.copy()
        step[:3, 3] *= scale
        out.append(out[-1] @ step @ bias)
    return np.stack(out)


@pytest.fixture(scope="session")
def cache_dir(request, tmp_path_factory) -> Path:
    """msa-slam's cache for the session's simulated sequences and their front ends, in pytest's cache folder: the
    xdist workers and later runs share it instead of each simulating and computing the same again. Safe to share
    because every entry is keyed by its inputs' content and its code's fingerprint and written atomically
    (io/cache.py, sim/sequence.py); `pytest --cache-clear` (or `-p no:cacheprovider`: a temporary folder) starts
    cold."""
    if getattr(request.config, "cache", None) is None:
        path = tmp_path_factory.getbasetemp() / "msa-pipeline-cache"
        path.mkdir(exist_ok=True)
        return path
    return request.config.cache.mkdir("msa-pipeline-cache")


@pytest.fixture(scope="session")
def sequence(cache_dir) -> Path:
    return simulate_sequence(DEFAULT_CONFIGS["test"], cache_dir=cache_dir)


@pytest.fixture(scope="session")
def odometry_file(sequence, cache_dir) -> Path:
    gt, _ = read_poses(sequence / "poses.txt")
    path = cache_dir / f"{sequence.name}.drifted-odometry.txt"  # one per simulation: the cache outlives a sequence
    if not path.exists():
        write_poses(path, drifted(gt))  # atomic: the other worker reads it whole or not at all
    return path


@pytest.fixture(scope="session")
def scans_only(tmp_path_factory):
    """The simulator's test sequence as a bare folder of .bin scans, and its poses as an odometry file."""
    sim = resolve_dataset("sim:test")
    folder = tmp_path_factory.mktemp("nogt") / "scans"
    folder.mkdir()
    for scan in sorted((sim / "velodyne").glob("*.bin"))[:90]:
        shutil.copy(scan, folder / scan.name)
    poses = folder.parent / "odometry.txt"
    poses.write_text("".join((sim / "poses.txt").read_text().splitlines(keepends=True)[:90]))
    return folder, poses
