"""Shared test helpers: locate ../shared (skip clearly when absent); the simulated sequences the tests run on; under
pytest-xdist, the kernels compiled once and the heaviest files first."""

from __future__ import annotations

import gc
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


# Test files of 6 s of CPU or more, heaviest first (docs/performance.md, "The test suite", 2026-12-05); the others,
# under 6 s each, follow in collection order. `make test` hands whole files to pytest-xdist's workers in this order
# (`--dist loadfile --no-loadscope-reorder`; xdist's own order puts the files with the most tests first, which left
# heavy files of few tests for the end, where one worker finished one while the other waited).
HEAVIEST_FIRST = (
    "test_msa_parity.py",
    "test_pipeline.py",
    "test_compare_workers.py",
    "test_local_map_loops.py",
    "test_sim.py",
    "test_experiments.py",
    "test_trust_cache_identity.py",
    "test_memory_accounting.py",
    "test_live_odometry_cache.py",
    "test_online.py",
    "test_sim_world.py",
    "test_never_worse.py",
    "test_messages_real.py",
    "test_single_open.py",
    "test_experiment_sharing.py",
    "test_cli_run.py",
    "test_reproduce.py",
    "test_no_ground_truth.py",
    "test_read_ahead.py",
    "test_report_any_folder.py",
    "test_msa_canonical.py",
    "test_deskew_sim.py",
    "test_cache.py",
    "test_golden_outputs.py",
    "test_outputs_files.py",
    "test_overlap_transformer.py",
    "test_loop_accounting.py",
    "test_faults.py",
    "test_viewer.py",  # under 6 s of CPU, more in wall time: an online run recorded for the viewer
    "test_packaging.py",  # a wheel built by pip
)
KERNELS = pytest.StashKey["KernelCompilation"]()
FROZEN_FILE = pytest.StashKey[Path]()


@pytest.hookimpl(trylast=True)  # after the terminal reporter is set up
def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist (`make test`), start compiling the numba kernels once, in processes of the controller's,
    while its workers start and collect the tests, instead of once in each worker on a fresh clone
    (helpers/kernels.py); the workers get their first tests once the kernels are compiled."""
    if hasattr(config, "workerinput") or (config.getoption("numprocesses", 0) or 0) < 2 or config.option.collectonly:
        return
    from helpers.kernels import KernelCompilation

    reporter = config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.write_line("compiling the numba kernels once for the workers (on a fresh clone: about a minute)")
    config.stash[KERNELS] = compiling = KernelCompilation()
    config.add_cleanup(compiling.wait)  # also when the session ends before a worker has collected


@pytest.hookimpl(optionalhook=True)  # a pytest-xdist hook: without xdist there is nothing to wait for
def pytest_xdist_node_collection_finished(node, ids: list[str]) -> None:
    """In the controller, before the workers' first tests are handed out: wait for the kernels' compilation."""
    compiling = node.config.stash.get(KERNELS, None)
    if compiling is not None:
        compiling.wait()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """In a pytest-xdist worker, put the files of HEAVIEST_FIRST first, in its order; a file's tests keep theirs."""
    if hasattr(config, "workerinput"):
        rank = {name: position for position, name in enumerate(HEAVIEST_FIRST)}
        items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # a stable sort


@pytest.hookimpl(tryfirst=True)  # before the file's fixtures are set up
def pytest_runtest_setup(item: pytest.Item) -> None:
    """At each test file's first test: collect the garbage, then freeze what is left (gc.freeze).

    Why: msa-slam collects the garbage in full at each back end's start and end (evaluation/resources.py's
    settle_heap, so that an RSS reading is not lowered later by memory freed before it), several times per run
    (a threshold sweep replays the back end four times). In a pytest process, which holds the suite's imports, its
    collected tests and the session's fixtures (about 300,000 objects), each such collection cost about a tenth of a
    second of CPU, most of it going through objects no run made; frozen, they are skipped, and what a run or a test
    leaves as garbage is collected as before. What a file freed is collected before the next file's freeze (a
    file's module fixtures are torn down by then), so that collection too goes only through what the file made;
    an object frozen while in use and freed in a later file stays until the session ends (or until msa-slam's
    forked workers unfreeze every object, workers.py)."""
    if item.config.stash.get(FROZEN_FILE, None) != item.path:
        item.config.stash[FROZEN_FILE] = item.path
        gc.collect()
        gc.freeze()


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
