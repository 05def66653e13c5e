"""What a finished result depends on besides its config: the content of its input data and msa-slam's code.

Results that a later run reuses (an experiment's cells, the seeds of `compare --seeds`) are recognised by
their config, so a resume after the dataset's scans (or a file the config names, e.g. a pose file or network
weights) or the code changed would otherwise report old results beside new ones. Each records
{"data": ..., "code": ...} (run_identities) and a resume reruns the ones whose record differs from the current one
(changed_identity). The data identity is computed before any work and cheaply: a folder or bag by the content
of the scans a config selects (with their frame times and ground truth), through the pipeline cache's memo of
file digests, so only new or changed files are read; a `sim:` or `live:` dataset by its simulation key (config
and simulator code), without simulating it, so the seeds of a simulated dataset differ by their world seed.
The code identity is the fingerprint of the whole package (a run uses nearly all of it); it also covers
msa-slam's version, which lives in the package's __init__.py, so a result of another version is rerun rather
than refused.

A grid's cell records its identity in its cell.json (experiments.cell_info), a seed of `compare --seeds` in its seed.json.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import JSONValue
from msa_slam.experiments.folder import FinishedCells
from msa_slam.experiments.grid import Cell
from msa_slam.io.cache import CacheDir, array_sha256, input_identity, named_files, pipeline_cache, sequence_identity
from msa_slam.io.fingerprint import PACKAGE, code_fingerprint

CODE = (PACKAGE,)  # what the code identity fingerprints
PARTS = ("data", "code")  # the parts of an identity
Run = TypeVar("Run")  # what names a run: a cell id, a seed


def _digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()[:24]


def code_identity() -> str:
    """The fingerprint of msa-slam's whole package (computed once per process), shortened as records keep it."""
    return code_fingerprint(CODE)[:24]


def dataset_identity(config: Mapping[str, Any], cache: CacheDir) -> dict[str, JSONValue]:
    """Identity of the data a run `config` reads: the simulation key of a sim:/live: dataset, else the identity
    of the scans its source options select (msa_slam.io.cache.sequence_identity) and of their ground truth."""
    from msa_slam.datasets import SourceOptions, open_source_options
    from msa_slam.sources import parse_spec

    spec = parse_spec(config["dataset"])
    if spec.simulated:
        return {"simulation": spec.config.key()}
    sequence = open_source_options(spec.path, config["dataset_kind"], SourceOptions(**config["source"]))
    ground_truth = None if sequence.gt_poses is None else array_sha256(sequence.gt_poses)
    return {"scans": sequence_identity(sequence, cache), "ground_truth": ground_truth}


class DataIdentities:
    """The data identity of run configs (dumped RunConfig or OnlineConfig), each dataset selection opened once and
    each cache's digest memo shared by all the configs a run checks."""

    def __init__(self) -> None:
        self._caches: dict[str | None, CacheDir] = {}
        self._datasets: dict[str, dict[str, JSONValue] | None] = {}  # selection -> its identity (None: unreadable)

    def __call__(self, configs: Sequence[Mapping[str, Any]]) -> str | None:
        """Identity of what `configs` (runs on one dataset selection, e.g. a comparison's methods) read: the
        dataset and every file the configs name; None when the dataset cannot be opened now (the run then fails
        when it starts, with the reason)."""
        config = configs[0]
        cache_dir = config.get("cache_dir")
        cache = self._caches.setdefault(cache_dir, CacheDir(pipeline_cache(cache_dir)))
        selection = _digest([config["dataset"], config["dataset_kind"], config["source"], cache_dir])
        if selection not in self._datasets:
            try:
                self._datasets[selection] = dataset_identity(config, cache)
            except InputError:
                self._datasets[selection] = None
        if self._datasets[selection] is None:
            return None
        named = named_files([{k: v for k, v in c.items() if k != "dataset"} for c in configs])
        files = input_identity(list(dict.fromkeys(named)), cache=cache)
        return _digest({"dataset": self._datasets[selection], "files": files})


def run_identities(runs: Mapping[Run, Sequence[Mapping[str, Any]]]) -> dict[Run, dict[str, str | None]]:
    """{"data": ..., "code": ...} of each run (name -> the configs it runs; DataIdentities)."""
    code, data = code_identity(), DataIdentities()
    return {name: {"data": data(configs), "code": code} for name, configs in runs.items()}


def changed_identity(recorded: Any, current: Mapping[str, str | None]) -> str | None:
    """Why a result that recorded identity `recorded` must be rerun now that it is `current`, None when it need
    not: the parts (data, code) that changed, or that it records none (an older msa-slam made it). A current
    part of None (the data cannot be read now) counts as changed."""
    if not isinstance(recorded, dict):
        return "it records no identity of its data and code (an older msa-slam ran it)"
    changed = [part for part in PARTS if current[part] is None or recorded.get(part) != current[part]]
    return f"its {' and '.join(changed)} changed since it ran" if changed else None


def cell_identities(cells: list[Cell]) -> dict[str, dict[str, str | None]]:
    """{"data": ..., "code": ...} of every cell by id; "data" is None when the dataset cannot be opened now (the
    cell then fails when it runs, with the reason). Each dataset selection is opened once."""
    return run_identities({cell.id: [cell.config] for cell in cells})


def outdated_cells(finished: FinishedCells, identities: dict[str, dict[str, str | None]]) -> dict[str, str]:
    """The `finished` cells whose recorded identity differs from `identities` (cell_identities), each with the
    line that says why it is rerun."""
    out = {}
    for cell_id, cell in finished.items():
        reason = changed_identity(cell.info.identity, identities[cell_id])
        if reason is not None:
            out[cell_id] = f"cell {cell_id}: {reason}; rerun"
    return out
