"""The KISS-ICP odometry of a live: source, computed once (pipeline.live.prepare_live_odometry, before a grid's
cells) and replayed by every online run on it: the runs write the same bytes as runs that register every frame
themselves, a shorter run replays the first frames, and only single-threaded KISS-ICP is shared."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from msa_slam.experiments.grid import GridSpec, expand
from msa_slam.experiments.inputs import input_groups
from msa_slam.pipeline import run
from msa_slam.pipeline.config import make_online_config
from msa_slam.pipeline.live import prepare_live_odometry
from msa_slam.reporting.results import write_run_files

DRIVE = "live:city-tour,stride=4,azimuth_steps=180,end=100,laps=2"  # 50 frames, the second pass a revisit
# metrics.json keys that hold times, the process's memory or whether the odometry was replayed: all else must agree
MEASURED = {
    "time_s",
    "pipeline_time_s",
    "fps",
    "backend_fps",
    "realtime_factor",
    "latency_ms",
    "odometry_cached",
    "replayed_time_s",
    "peak_rss_bytes",
    "rss_growth_bytes",
    "rss_growth_ratio",
}
# steps.csv: per-frame times and process RSS; provenance.json: the date it was written
TIMED_FILES = {"metrics.json", "report.md", "steps.csv", "provenance.json"}


def _written(config, folder: Path) -> dict[str, bytes]:
    folder.mkdir()
    write_run_files(run(config), folder, figures=False)
    return {str(f.relative_to(folder)): f.read_bytes() for f in sorted(folder.rglob("*")) if f.is_file()}


def test_runs_replaying_the_prepared_odometry_write_the_same_bytes(tmp_path):
    config = make_online_config(
        dataset=DRIVE,
        odometry="kiss",
        odometry_params={"num_threads": 1},
        sampler="constant",
        sampler_params={"distance": 2.0},
        mode="realistic",
        max_frames=40,  # a prefix: replayed from the entry of all 50 frames
        cache_dir=str(tmp_path / "cache"),
    )
    alone = _written(config, tmp_path / "alone")
    assert not list((tmp_path / "cache").rglob("odometry-*"))  # a run alone stores nothing
    assert prepare_live_odometry(config)
    assert len(list((tmp_path / "cache").rglob("odometry-*.npy"))) == 1
    shared = _written(config, tmp_path / "shared")
    assert alone.keys() == shared.keys() and "trajectories/odometry.kitti" in alone
    assert {name for name in alone if alone[name] != shared[name]} <= TIMED_FILES
    first, second = (json.loads(files["metrics.json"]) for files in (alone, shared))
    assert (first["odometry_cached"], second["odometry_cached"]) == (False, True)
    assert first["frames"] == 40 and first["keyframes"] > 3
    assert {k: v for k, v in first.items() if k not in MEASURED} == {
        k: v for k, v in second.items() if k not in MEASURED
    }
    assert prepare_live_odometry(config)  # found in the cache: nothing computed again
    assert len(list((tmp_path / "cache").rglob("odometry-*.npy"))) == 1


def test_other_odometry_is_not_prepared(tmp_path):
    config = make_online_config(dataset=DRIVE, odometry="gt-noise", cache_dir=str(tmp_path / "cache"))
    assert not prepare_live_odometry(config)
    assert not list(tmp_path.rglob("odometry-*"))


@pytest.mark.parametrize(
    "base, groups",
    [
        ({"odometry": "kiss", "odometry_params": {"num_threads": 1}}, 2),  # one preparation per dataset
        ({"odometry": "gt-noise"}, 0),  # nothing to build: each cell perturbs ground truth itself
    ],
)
def test_online_cells_on_a_live_source_share_one_preparation(base, groups):
    grid = GridSpec(
        name="g",
        pipeline="online",
        datasets=[DRIVE, DRIVE.replace("laps=2", "laps=3")],
        samplers=[{"sampler": "all"}, {"sampler": "constant"}],
        seeds=[0],
        base=base,
    )
    found = input_groups(expand(grid))
    assert len(found) == groups and all(len(group) == 1 for group in found)


def test_estimate_counts_a_live_sources_shared_odometry_once():
    """Online cells on one live: source: each simulates, describes and runs its back end; KISS-ICP on one thread
    runs once, over all the source's frames (simulated once more for it), not once a cell."""
    from msa_slam.experiments.estimate import REFERENCE_POINTS, STAGE_S, estimate_grid

    def grid(odometry: dict) -> list:
        spec = {"name": "g", "pipeline": "online", "datasets": [DRIVE], "seeds": [0], "base": odometry}
        return expand(GridSpec(**spec, samplers=[{"sampler": "all"}, {"sampler": "constant"}, {"sampler": "msa"}]))

    def seconds(odometry: dict) -> float:
        cells = grid(odometry)
        found = estimate_grid("g", cells, {}, cells, workers=1)
        assert found.seconds is not None
        return found.seconds

    frames, scale = 50, 64 * 180 / REFERENCE_POINTS  # DRIVE: 2 x 25 frames of 64 x 180 points
    per_cell = frames * (STAGE_S["simulation"] * scale + STAGE_S["descriptor"] + STAGE_S["back end"])
    registered = frames * STAGE_S["kiss-icp"] * scale
    shared = seconds({"odometry": "kiss"})  # grid cells run KISS-ICP on one thread
    assert shared == pytest.approx(3 * per_cell + registered + frames * STAGE_S["simulation"] * scale)
    several = seconds({"odometry": "kiss", "odometry_params": {"num_threads": 2}})  # not reproducible: not shared
    assert several == pytest.approx(3 * (per_cell + registered))
    assert seconds({"odometry": "gt-noise"}) == pytest.approx(3 * per_cell)


def test_reproduce_estimate_runs_nothing(tmp_path, monkeypatch):
    from msa_slam.experiments.reproduce import estimate_reproduction

    monkeypatch.chdir(tmp_path)
    lines = estimate_reproduction(["paper-table2", "paper-ablation"], quick=True, workers=2)
    assert lines[0].startswith("grid paper-table2-quick: 6 cells, 0 finished earlier, 6 to run; estimated time ")
    assert "2 copied from an identical cell" in lines[1]  # all samples and MSA: the same runs as Table II's
    assert lines[-1].startswith("all 2 grid(s): estimated ") and list(tmp_path.iterdir()) == []


def test_a_grid_in_one_process_registers_a_live_source_once(tmp_path):
    """The cells of a grid run one after the other replay the odometry prepared before them, as on workers."""
    from msa_slam.experiments.runner import run_grid

    base = {"odometry": "kiss", "mode": "realistic", "max_frames": 30, "cache_dir": str(tmp_path / "cache")}
    grid = GridSpec(
        name="g",
        pipeline="online",
        datasets=[DRIVE],
        samplers=[{"sampler": "all"}, {"sampler": "constant", "params": {"distance": 2.0}}],
        base=base,
    )
    done = run_grid(grid, tmp_path / "out")
    assert len(done.ran) == 2 and not done.failed
    cached = [json.loads(p.read_text())["odometry_cached"] for p in sorted((tmp_path / "out").rglob("metrics.json"))]
    assert cached == [True, True]
    assert len(list((tmp_path / "cache").rglob("odometry-*.npy"))) == 1
