"""Cells that compute the same run, in one grid or in two, run once; the others are copies that say so."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_experiments import TINY

from msa_slam.experiments import runner
from msa_slam.experiments.cell_info import RUN_KEY, SHARED_FROM
from msa_slam.experiments.folder import load_cells
from msa_slam.experiments.grid import expand, parse_grid, run_key
from msa_slam.experiments.paper import PRESETS, paper_grids
from msa_slam.experiments.sharing import plan_sharing

IDENTITY = {"data": "d", "code": "c"}


def _keys(cells, identity=IDENTITY):
    return {c.id: run_key(c, identity) for c in cells}


def test_run_key_is_what_the_cell_computes_not_its_label():
    grid = parse_grid(
        {
            **TINY,
            "samplers": [
                "msa",
                {"label": "msa-defaults", "sampler": "msa", "params": {"lambda_l": 0.1, "lambda_u": 3}},
                {"label": "msa-wide", "sampler": "msa", "params": {"lambda_u": 5.0}},
            ],
            "seeds": [0, 1],
        }
    )
    cells = {(c.method, c.seed): c for c in expand(grid)}
    key = run_key(cells["msa", 0], IDENTITY)
    assert run_key(cells["msa-defaults", 0], IDENTITY) == key  # the defaults spelled out: the same run
    assert run_key(cells["msa-wide", 0], IDENTITY) != key
    assert run_key(cells["msa", 1], IDENTITY) != key
    assert run_key(cells["msa", 0], {"data": "d", "code": "other"}) != key  # other code: another run
    assert run_key(cells["msa", 0], {"data": None, "code": "c"}) is None  # unreadable data: never shared


@pytest.mark.parametrize("quick, cells, runs", [(True, 32, 29), (False, 450, 432)])
def test_the_paper_grids_run_each_distinct_cell_once(quick, cells, runs):
    # all samples and MSA recur in Table II, the ablation and the bounds (in the full run the last two cut the
    # drive shorter: their own); lambda_u = 3 with lambda_l = 0.1 is MSA's default, and the two bound sweeps meet at
    # lambda_l = 0.1, lambda_u = 5
    finished: dict = {}  # run key -> folder, as reproduce runs the grids one after the other
    total = ran = 0
    for name, grid in paper_grids(PRESETS, quick, None).items():
        todo = expand(grid)
        keys = _keys(todo)
        plan = plan_sharing(todo, keys, finished)
        assert len(plan.run) + len(plan.copies) + len(plan.after) == len(todo)
        total, ran = total + len(todo), ran + len(plan.run)
        finished.update({keys[c.id]: Path(name, c.id) for c in todo})
    assert (total, ran) == (cells, runs)


def test_identical_cells_run_once_and_the_copies_say_where_from(tmp_path, monkeypatch):
    ran = []
    real = runner.run_cell

    def counted(info, config, out, figures=False):
        ran.append(info.method)
        return real(info, config, out, figures)

    monkeypatch.setattr(runner, "run_cell", counted)
    twin = {**TINY, "samplers": ["all", {"label": "all-again", "sampler": "all"}]}
    first = runner.run_grid(parse_grid(twin), tmp_path / "a")
    assert ran == ["all"] and len(first.ran) == 1 and not first.failed
    (cell, again) = expand(parse_grid(twin))
    assert first.shared == {again.id: cell.id}
    record = json.loads((tmp_path / "a" / "cells" / again.id / "cell.json").read_text())
    assert record[SHARED_FROM] == f"../{cell.id}" and record["method"] == "all-again"
    assert record[RUN_KEY] == json.loads((tmp_path / "a" / "cells" / cell.id / "cell.json").read_text())[RUN_KEY]
    rows = {c.info.method: c.metrics.run.keyframes for c in load_cells(tmp_path / "a")}
    assert rows["all"] == rows["all-again"] > 0
    # another grid with the same run, told of the first folder: a copy, nothing run
    other = runner.run_grid(
        parse_grid({**TINY, "name": "u", "samplers": ["all"]}), tmp_path / "b", share_from=[tmp_path / "a"]
    )
    assert ran == ["all"] and not other.ran and list(other.shared.values()) in ([cell.id], [again.id])
    assert (tmp_path / "b" / "cells" / next(iter(other.shared)) / "metrics.json").read_bytes() == (
        tmp_path / "a" / "cells" / cell.id / "metrics.json"
    ).read_bytes()


def test_parallel_workers_do_not_both_build_an_input(tmp_path, monkeypatch):
    # two batch cells on one uncached simulated sequence, on two workers at once: the simulation and the front end
    # are built once, by the preparation before the cells start, and both cells read them from the cache
    distributed = pytest.importorskip("distributed")
    from msa_slam.pipeline import read_ahead
    from msa_slam.sim import sequence

    builds = []

    def counting(module, name):
        real = getattr(module, name)

        def wrapper(*args, **kwargs):
            builds.append(name)
            return real(*args, **kwargs)

        monkeypatch.setattr(module, name, wrapper)

    counting(sequence, "_write")  # casts the scans of a simulation not yet cached
    counting(read_ahead, "save_descriptors")  # stores descriptors computed (not read from the cache)
    grid = parse_grid(
        {
            **TINY,
            "pipeline": "batch",
            # the first 200 frames (50 scans): what is built and how often does not depend on the length
            "datasets": ["sim:figure-eight,end=200,stride=4,azimuth_steps=180"],
            "base": {"odometry": "kiss", "sample_on": "gt", "min_frame_gap": 20, "cache_dir": str(tmp_path / "cache")},
        }
    )
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster,
        distributed.Client(cluster) as client,
    ):
        run = runner.run_grid(grid, tmp_path / "out", client=client)
    assert len(run.ran) == 2 and not run.failed
    assert builds == ["_write", "save_descriptors"]
