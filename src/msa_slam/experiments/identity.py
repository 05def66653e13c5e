"""What a cell's results depend on besides its config: the content of its input data and msa-slam's code.

A cell's id hashes its config only, so a resume after the dataset's scans (or a file the config names, e.g. a
pose file or network weights) or the code changed would otherwise report old cells beside new ones. Each cell
records {"data": ..., "code": ...} in its cell.json (CELL_IDENTITY); a resume reruns the finished cells whose
record differs from the current one. The data identity is computed before any cell runs and cheaply: a folder
or bag by the content of the scans a cell selects (with their frame times and ground truth), through the
pipeline cache's memo of file digests, so only new or changed files are read; a `sim:` or `live:` dataset by
its simulation key (config and simulator code), without simulating it. The code identity is the fingerprint
of the whole package (a cell runs nearly all of it); it also covers msa-slam's version, which lives in the
package's __init__.py, so a cell of another version is rerun rather than refused.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from msa_slam.errors import InputError
from msa_slam.experiments.folder import FinishedCells
from msa_slam.experiments.grid import Cell
from msa_slam.io.cache import CacheDir, array_sha256, input_identity, named_files, sequence_identity
from msa_slam.io.fingerprint import PACKAGE, code_fingerprint

CELL_IDENTITY = "identity"  # the key of cell.json that records it
CELL_CODE = (PACKAGE,)


def _digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()[:24]


def dataset_identity(config: dict[str, Any], cache: CacheDir) -> Any:
    """Identity of the data a cell `config` reads: the simulation key of a sim:/live: dataset, else the identity
    of the scans its source options select (msa_slam.io.cache.sequence_identity) and of their ground truth."""
    from msa_slam.datasets import SourceOptions, open_source_options
    from msa_slam.pipeline.source import SIM_PREFIX, sim_config
    from msa_slam.sim.live import LIVE_PREFIX, live_settings

    spec = config["dataset"]
    if spec.startswith(SIM_PREFIX):
        return {"simulation": sim_config(spec).key()}
    if spec.startswith(LIVE_PREFIX):
        return {"simulation": live_settings(spec)[0].key()}
    sequence = open_source_options(Path(spec).expanduser(), config["dataset_kind"], SourceOptions(**config["source"]))
    ground_truth = None if sequence.gt_poses is None else array_sha256(sequence.gt_poses)
    return {"scans": sequence_identity(sequence, cache), "ground_truth": ground_truth}


def cell_identities(cells: list[Cell]) -> dict[str, dict[str, str | None]]:
    """{"data": ..., "code": ...} of every cell by id; "data" is None when the dataset cannot be opened now (the
    cell then fails when it runs, with the reason). Each dataset selection is opened once."""
    from msa_slam.pipeline.frontend import pipeline_cache

    code = code_fingerprint(CELL_CODE)[:24]
    caches: dict[str | None, CacheDir] = {}
    datasets: dict[str, Any] = {}
    out = {}
    for cell in cells:
        config = cell.config
        cache_dir = config.get("cache_dir")
        cache = caches.setdefault(cache_dir, CacheDir(pipeline_cache(cache_dir)))
        selection = _digest([config["dataset"], config["dataset_kind"], config["source"], cache_dir])
        if selection not in datasets:
            try:
                datasets[selection] = dataset_identity(config, cache)
            except InputError:
                datasets[selection] = None
        if datasets[selection] is None:
            out[cell.id] = {"data": None, "code": code}
            continue
        files = input_identity(named_files({k: v for k, v in config.items() if k != "dataset"}), cache=cache)
        out[cell.id] = {"data": _digest({"dataset": datasets[selection], "files": files}), "code": code}
    return out


def outdated_cells(finished: FinishedCells, identities: dict[str, dict[str, str | None]]) -> dict[str, str]:
    """The `finished` cells whose recorded identity differs from `identities` (cell_identities), each with the
    line that says why it is rerun."""
    out = {}
    for cell_id, (info, _) in finished.items():
        recorded = info.get(CELL_IDENTITY)
        if not isinstance(recorded, dict):
            out[cell_id] = f"cell {cell_id}: it records no identity of its data and code (an older msa-slam ran it); " \
                           "rerun"
            continue
        current = identities[cell_id]
        changed = [part for part in ("data", "code") if current[part] is None or recorded.get(part) != current[part]]
        if changed:
            out[cell_id] = f"cell {cell_id}: its {' and '.join(changed)} changed since it ran; rerun"
    return out
