"""Experiment grids: a YAML file naming datasets x descriptors x samplers x parameters x seeds, validated
with pydantic (an unknown key is an error listing the valid ones) and expanded into cells, each a complete
pipeline config with a stable id (a hash of that config), so a re-run recognises finished cells.

    name: ablation
    pipeline: online            # online (the paper's Table II protocol, iSAM2) or batch (Table I, LM)
    datasets: ["live:city-tour,stride=2,azimuth_steps=360"]   # `{seed}` in a dataset is replaced
    descriptors: [sc]
    samplers:
      - all                     # a sampler name, or a mapping:
      - {label: msa-alpha10, sampler: msa, params: {alpha: 10}}
      - {label: msa, sampler: msa, sweep: {lambda_l: [0, 0.5, 1]}}   # one cell per value
    parameters: {similarity_threshold: [0.8]}   # product over all cells; keys as in --param
    seeds: [0, 1]               # online: odometry noise seed (and {seed} in datasets)
    base: {odometry: gt-noise, mode: oracle}    # config keys shared by every cell
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Mapping

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from msa_slam.config import validation_message
from msa_slam.errors import InputError

GRID_DIR = Path(__file__).parent / "grids"


def _every_key_has_values(what: str, v: dict[str, list[Any]]) -> dict[str, list[Any]]:
    """An empty value list would expand the grid to no cells at all."""
    for key, values in v.items():
        if not values:
            raise ValueError(f"{what} {key!r} has no values (the grid would have no cells)")
    return v


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class SamplerSpec(_Strict):
    """One method of the grid: a sampler with parameters; `sweep` expands into one method per value."""

    sampler: str
    label: str | None = None
    params: dict[str, Any] = Field(default_factory=dict)
    sweep: dict[str, list[Any]] = Field(default_factory=dict)

    @field_validator("sweep")
    @classmethod
    def _non_empty(cls, v: dict[str, list[Any]]) -> dict[str, list[Any]]:
        return _every_key_has_values("sweep", v)


class GridSpec(_Strict):
    """A whole experiment grid (see the module docstring for the YAML layout)."""

    name: str = "grid"
    pipeline: Literal["online", "batch"] = "online"
    datasets: list[str] = Field(min_length=1)
    descriptors: list[str] = Field(default_factory=lambda: ["sc"], min_length=1)
    samplers: list[SamplerSpec] = Field(min_length=1)
    parameters: dict[str, list[Any]] = Field(default_factory=dict)
    seeds: list[int] = Field(default_factory=lambda: [0], min_length=1)
    base: dict[str, Any] = Field(default_factory=dict)
    reference: str | None = None  # default: `all` when the grid has it, else its first method
    figures: bool = False

    @field_validator("parameters")
    @classmethod
    def _non_empty(cls, v: dict[str, list[Any]]) -> dict[str, list[Any]]:
        return _every_key_has_values("parameters", v)

    @model_validator(mode="before")
    @classmethod
    def _sampler_names(cls, data: Any) -> Any:
        """A bare sampler name stands for {sampler: NAME}."""
        if isinstance(data, dict) and isinstance(data.get("samplers"), list):
            data = {**data, "samplers": [{"sampler": s} if isinstance(s, str) else s for s in data["samplers"]]}
        return data

    def methods(self) -> list[tuple[str, str, dict[str, Any], dict[str, Any]]]:
        """(label, sampler, params, swept values) of every method after expanding sweeps."""
        out = []
        for spec in self.samplers:
            label = spec.label or spec.sampler
            keys = list(spec.sweep)
            for values in itertools.product(*(spec.sweep[k] for k in keys)):
                swept = dict(zip(keys, values))
                suffix = "".join(f" {k}={v}" for k, v in swept.items())
                out.append((label + suffix, spec.sampler, {**spec.params, **swept}, swept))
        labels = [m[0] for m in out]
        duplicates = sorted({x for x in labels if labels.count(x) > 1})
        if duplicates:
            raise InputError(f"grid {self.name!r}: method labels repeat ({', '.join(duplicates)}); give each a label")
        return out

    def labels(self) -> list[str]:
        """The method labels (what `reference` and `report --reference` may name)."""
        return [m[0] for m in self.methods()]

    def reference_method(self) -> str:
        """The method memory and ATE differences are relative to."""
        labels = self.labels()
        return self.reference or ("all" if "all" in labels else labels[0])


@dataclass(frozen=True)
class Cell:
    """One run of the grid: its id (folder name), what it varies, and its full pipeline config."""

    id: str
    pipeline: str
    dataset: str
    descriptor: str
    method: str
    sampler: str
    swept: dict[str, Any]
    parameters: dict[str, Any]
    seed: int
    config: dict[str, Any]
    index: int = 0  # position in the grid's expansion (report order)

    def info(self) -> dict[str, Any]:
        return {"id": self.id, "index": self.index, "pipeline": self.pipeline, "dataset": self.dataset,
                "descriptor": self.descriptor, "method": self.method, "sampler": self.sampler, "swept": self.swept,
                "parameters": self.parameters, "seed": self.seed}


def parse_grid(data: Any, where: str = "grid") -> GridSpec:
    """A validated GridSpec from a mapping; problems become one InputError naming `where`."""
    if not isinstance(data, Mapping):
        raise InputError(f"{where}: expected a mapping with keys {', '.join(GridSpec.model_fields)}")
    try:
        grid = GridSpec(**data)
    except ValidationError as exc:
        raise InputError(f"{where}: {validation_message(exc, GridSpec, 'grid')}") from None
    expand(grid, where)  # every cell must be a valid config before anything runs
    methods = grid.labels()
    if grid.reference is not None and grid.reference not in methods:
        raise InputError(f"{where}: reference {grid.reference!r} is not a method of the grid; methods: "
                         f"{', '.join(methods)} (set `reference:` to one of them)")
    return grid


def load_grid(path: str | os.PathLike) -> GridSpec:
    """Read a grid YAML file, or a shipped preset by name (table2, ablation, distance_bounds, tiny)."""
    path = Path(path)
    if not path.is_file() and (GRID_DIR / f"{path}.yaml").is_file():
        path = GRID_DIR / f"{path}.yaml"
    if not path.is_file():
        presets = ", ".join(sorted(p.stem for p in GRID_DIR.glob("*.yaml")))
        raise InputError(f"{path}: grid file not found (shipped presets: {presets})")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML ({exc})") from None
    return parse_grid(data, str(path))


def slug(text: str) -> str:
    """`text` as a short file-name-safe word (cell ids, figure names)."""
    return re.sub(r"[^A-Za-z0-9=.+-]+", "_", text).strip("_")[:60]


def _config_for(grid: GridSpec, dataset: str, descriptor: str, sampler: str, params: dict[str, Any],
                parameters: dict[str, Any], seed: int, label: str, where: str) -> dict[str, Any]:
    from msa_slam.pipeline.config import make_config
    from msa_slam.pipeline.online_config import apply_online_params
    from msa_slam.pipeline.config import apply_params

    data = {**grid.base, "dataset": dataset.replace("{seed}", str(seed)), "descriptor": descriptor,
            "sampler": sampler, "sampler_params": params, "label": label}
    overrides = [f"{k}={json.dumps(v)}" for k, v in parameters.items()]
    try:
        if grid.pipeline == "online":
            return apply_online_params({**data, "seed": seed}, overrides).dump()
        return apply_params(make_config(data), overrides).dump()
    except InputError as exc:
        raise InputError(f"{where}: cell {label!r} on {dataset!r}: {exc}") from None


def expand(grid: GridSpec, where: str = "grid") -> list[Cell]:
    """All cells of the grid in a stable order; each config validated (sampler parameters included)."""
    from msa_slam.sampling import make_sampler

    methods = grid.methods()
    keys = list(grid.parameters)
    cells = []
    for dataset, descriptor, (label, sampler, params, swept), values, seed in itertools.product(
            grid.datasets, grid.descriptors, methods, itertools.product(*(grid.parameters[k] for k in keys)),
            grid.seeds):
        parameters = dict(zip(keys, values))
        config = _config_for(grid, dataset, descriptor, sampler, params, parameters, seed, label, where)
        try:
            make_sampler(config["sampler"], **config["sampler_params"])
        except InputError as exc:
            raise InputError(f"{where}: method {label!r}: {exc}") from None
        digest = hashlib.sha256(json.dumps({"pipeline": grid.pipeline, "config": config}, sort_keys=True,
                                           default=str).encode()).hexdigest()[:10]
        name = slug(f"{dataset.split(',')[0]}-{descriptor}-{label}"
                     + "".join(f"-{k}={v}" for k, v in parameters.items()) + f"-s{seed}")
        cells.append(Cell(f"{name}-{digest}", grid.pipeline, dataset, descriptor, label, sampler, swept, parameters,
                          seed, config, len(cells)))
    ids = [c.id for c in cells]
    if len(set(ids)) != len(ids):
        raise InputError(f"{where}: some cells have identical configs (repeated datasets, seeds or methods)")
    return cells
