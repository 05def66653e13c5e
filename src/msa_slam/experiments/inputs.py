"""The inputs a grid's cells share, built once before the cells run in parallel.

Cells on one dataset share its simulation (a sim: sequence, cached on disk), batch cells its front end
(odometry, descriptors, downsampled clouds: cached per sequence) and online cells on a live: source its KISS-ICP
odometry when registered on one thread (cached by the source's identity: pipeline.live.prepare_live_odometry;
each online cell still simulates the frames and describes them as it reads them). Run at once on several
workers, each cell would find them missing and build them itself: the same work two or more times, and
simulations of one sequence racing for its cache folder; an online cell on a live: source would not store its
odometry at all. So before the cells run (on parallel workers, a local cluster or a Dask scheduler, or one after
the other in this process) each dataset's inputs are built by one task (prepare_inputs), the datasets' tasks side
by side; the cells then read them from the cache. A dataset whose preparation fails is left to its cells, which
record why.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from msa_slam.experiments.grid import Cell
from msa_slam.sources.spec import spec_kind

# The config keys the cached front end depends on beyond the dataset (pipeline.frontend.prepare_frontend).
FRONTEND_KEYS = ("odometry", "odometry_params", "descriptor", "descriptor_params", "loop_detector", "verifier")
# ... and the cached odometry of a live: source beyond the dataset (pipeline.live.prepare_live_odometry).
ONLINE_ODOMETRY_KEYS = ("odometry", "odometry_params")
Preparation = tuple[str, dict[str, Any]]  # (pipeline, a cell's config) whose inputs to build


def input_groups(cells: Sequence[Cell]) -> list[list[Preparation]]:
    """Per dataset (spec, loader, selection, cache folder), the distinct preparations its cells need: one per front
    end for batch cells; one simulation for online cells on a sim: dataset; one per KISS-ICP setting for online
    cells on a live: source. Datasets with nothing to build (recordings and live: sources read by online cells
    with another odometry) are left out."""
    groups: dict[str, dict[str, Preparation]] = {}
    for cell in cells:
        config = cell.config
        dataset = json.dumps(
            [config["dataset"], config.get("dataset_kind"), config.get("source"), config.get("cache_dir")],
            sort_keys=True,
            default=str,
        )
        if cell.pipeline == "batch":
            what = json.dumps({k: config.get(k) for k in FRONTEND_KEYS}, sort_keys=True, default=str)
        elif spec_kind(config["dataset"]) == "sim":
            what = "simulation"
        elif spec_kind(config["dataset"]) == "live" and config.get("odometry") == "kiss":
            what = json.dumps({k: config.get(k) for k in ONLINE_ODOMETRY_KEYS}, sort_keys=True, default=str)
        else:
            continue
        groups.setdefault(dataset, {}).setdefault(what, (cell.pipeline, config))
    return [list(found.values()) for found in groups.values()]


def prepare_inputs(preparations: Sequence[Preparation]) -> int:
    """Build one dataset's inputs (input_groups), one preparation after the other (the later ones find the
    simulation cached); a top-level function so Dask can ship it. Returns how many were prepared."""
    from msa_slam.pipeline.config import make_config, make_online_config
    from msa_slam.pipeline.frontend import prepare_frontend
    from msa_slam.pipeline.live import prepare_live_odometry, with_odometry_threads
    from msa_slam.sources import resolve_dataset

    for pipeline, config in preparations:
        if pipeline == "batch":
            prepare_frontend(make_config(config), quiet=True)
        elif spec_kind(config["dataset"]) == "live":
            prepare_live_odometry(with_odometry_threads(make_online_config(config), 1), quiet=True)  # as run_cell
        else:
            resolve_dataset(config["dataset"], config.get("cache_dir"))
    return len(preparations)
