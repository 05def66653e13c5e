"""What an experiment cell runs (the grid's labels for it, its place in the grid: CellInfo, which a grid.Cell adds
its config to) and what its cell.json records of its run (CellRecord): also the identity of its data and code
(experiments.identity), its run key (grid.run_key) and, for a copy of an identical cell, the folder its files came
from (experiments.sharing)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import JSONValue

IDENTITY = "identity"  # cell.json: the identity of the cell's data and code when it ran
RUN_KEY = "run_key"  # cell.json: grid.run_key of the cell
SHARED_FROM = "shared_from"  # cell.json of a copied cell: the folder its files came from, relative to its own
_REQUIRED = object()


@dataclass(frozen=True)
class CellInfo:
    """What a cell of a grid runs, as the grid labels it; `swept` and `parameters` are the grid's values for it
    (sampler parameters swept, grid `parameters`: configuration values, as the grid file gives them)."""

    id: str
    index: int  # position in the grid's expansion (report order)
    pipeline: str
    dataset: str
    descriptor: str
    method: str
    sampler: str
    swept: Mapping[str, Any]
    parameters: Mapping[str, Any]
    seed: int


@dataclass(frozen=True)
class CellRecord(CellInfo):
    """A cell's cell.json: its labels, the identity of its data and code when it ran and its run key (None in a
    cell.json an older msa-slam wrote: such a cell is rerun, experiments.identity.changed_identity) and, for a
    copy, the folder its files came from."""

    identity: Mapping[str, JSONValue] | None = None
    run_key: str | None = None
    shared_from: str | None = None

    @classmethod
    def of(
        cls, cell: CellInfo, identity: Mapping[str, JSONValue] | None = None, run_key: str | None = None
    ) -> CellRecord:
        """The record of `cell` run on data and code of `identity`, as run key `run_key`."""
        labels = {f.name: getattr(cell, f.name) for f in fields(CellInfo)}
        return cls(**labels, identity=identity, run_key=run_key)

    def to_json(self) -> dict[str, JSONValue]:
        """cell.json: the labels, then the identity and run key a run recorded, then where a copy came from."""
        out: dict[str, JSONValue] = {
            "id": self.id,
            "index": self.index,
            "pipeline": self.pipeline,
            "dataset": self.dataset,
            "descriptor": self.descriptor,
            "method": self.method,
            "sampler": self.sampler,
            "swept": dict(self.swept),
            "parameters": dict(self.parameters),
            "seed": self.seed,
        }
        if self.identity is not None or self.run_key is not None:
            out |= {IDENTITY: None if self.identity is None else dict(self.identity), RUN_KEY: self.run_key}
        if self.shared_from is not None:
            out[SHARED_FROM] = self.shared_from
        return out

    @classmethod
    def from_json(cls, data: Any, where: str) -> CellRecord:
        """The record of a cell.json; InputError naming `where` and the key for a missing key or a wrong type."""
        if not isinstance(data, Mapping):
            raise InputError(f"{where}: expected a JSON object")

        def typed(key: str, kind: type, default: Any = _REQUIRED) -> Any:
            if key not in data and default is not _REQUIRED:
                return default
            value = data.get(key)
            if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
                raise InputError(f"{where}: {key}: expected {kind.__name__}, got {value!r}")
            return value

        identity, run_key = data.get(IDENTITY), data.get(RUN_KEY)
        return cls(
            id=typed("id", str),
            index=typed("index", int, 0),
            pipeline=typed("pipeline", str),
            dataset=typed("dataset", str),
            descriptor=typed("descriptor", str),
            method=typed("method", str),
            sampler=typed("sampler", str),
            swept=typed("swept", dict, {}),
            parameters=typed("parameters", dict),
            seed=typed("seed", int),
            identity=identity if isinstance(identity, dict) else None,
            run_key=run_key if isinstance(run_key, str) else None,
            shared_from=typed(SHARED_FROM, str, None),
        )
