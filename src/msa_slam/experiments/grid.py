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

A cell's config must be what its label says, so a key is set in one place only: `parameters` may not name a
key that a method sets in its `params` or `sweep`, and `base` may not set what the grid varies (dataset,
descriptor, sampler, seed, label: they belong in `datasets`, `descriptors`, `samplers`, `seeds`). `base:
{sampler_params: {...}}` applies to every method whose sampler takes those parameters, below the method's own
`params` and swept values. A batch grid has no seed of its own, so several `seeds` need `{seed}` in every dataset.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictInt, ValidationError, field_validator, model_validator

from msa_slam.config import validation_message
from msa_slam.errors import InputError
from msa_slam.experiments.cell_info import CellInfo
from msa_slam.io.yaml_file import read_yaml
from msa_slam.sources.spec import SEED, seeded

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
    seeds: list[Annotated[StrictInt, Field(ge=0)]] = Field(default_factory=lambda: [0], min_length=1)  # not true
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

    def methods(self, where: str = "grid") -> list[tuple[str, str, dict[str, Any], dict[str, Any]]]:
        """(label, sampler, params, swept values) of every method after expanding sweeps; params are the base
        sampler_params the sampler takes, then the method's params, then its swept values."""
        from msa_slam.sampling.registry import sampler_parameters

        shared = self.base.get("sampler_params") or {}
        out = []
        for spec in self.samplers:
            label = spec.label or spec.sampler
            try:
                base = {k: v for k, v in shared.items() if k in sampler_parameters(spec.sampler)} if shared else {}
            except InputError as exc:  # an unknown sampler name
                raise InputError(f"{where}: method {label!r}: {exc}") from None
            keys = list(spec.sweep)
            for values in itertools.product(*(spec.sweep[k] for k in keys)):
                swept = dict(zip(keys, values))
                suffix = "".join(f" {k}={v}" for k, v in swept.items())
                out.append((label + suffix, spec.sampler, {**base, **spec.params, **swept}, swept))
        labels = [m[0] for m in out]
        duplicates = sorted({x for x in labels if labels.count(x) > 1})
        if duplicates:
            raise InputError(f"{where}: method labels repeat ({', '.join(duplicates)}); give each a label")
        return out

    def labels(self) -> list[str]:
        """The method labels (what `reference` and `report --reference` may name)."""
        return [m[0] for m in self.methods()]

    def reference_method(self) -> str:
        """The method memory and ATE differences are relative to."""
        labels = self.labels()
        return self.reference or ("all" if "all" in labels else labels[0])


@dataclass(frozen=True)
class Cell(CellInfo):
    """One run of the grid: its id (folder name), what it varies, and its full pipeline config."""

    config: dict[str, Any]


# Config keys that name a run without changing what it computes: cells differing only there are one run.
PRESENTATION_KEYS = ("label",)


def run_key(cell: Cell, identity: Mapping[str, str | None]) -> str | None:
    """What the cell computes, as a hash: its pipeline, its config as run (the sampler's parameters with their
    defaults filled in; not its label) and the identity of its data and code (experiments.identity). Cells of
    one grid or of two with the same key are one run (experiments.sharing copies it); None when the data cannot
    be read now (such a cell is never shared)."""
    from msa_slam.sampling.registry import check_sampler_params

    if any(value is None for value in identity.values()):
        return None
    config = {k: v for k, v in cell.config.items() if k not in PRESENTATION_KEYS}
    config["sampler_params"] = check_sampler_params(cell.sampler, config.get("sampler_params") or {}).model_dump(
        mode="json"
    )
    content = {"pipeline": cell.pipeline, "config": config, "identity": dict(identity)}
    return hashlib.sha256(json.dumps(content, sort_keys=True, default=str).encode()).hexdigest()


def parse_grid(data: Any, where: str = "grid") -> GridSpec:
    """A validated GridSpec from a mapping; problems become one InputError naming `where`."""
    if not isinstance(data, Mapping):
        raise InputError(f"{where}: expected a mapping with keys {', '.join(GridSpec.model_fields)}")
    try:
        grid = GridSpec(**data)
    except ValidationError as exc:
        raise InputError(f"{where}: {validation_message(exc, GridSpec, 'grid')}") from None
    _check_one_place(grid, where)
    expand(grid, where)  # every cell must be a valid config before anything runs
    _check_base_sampler_params(grid, where)
    methods = grid.labels()
    if grid.reference is not None and grid.reference not in methods:
        raise InputError(
            f"{where}: reference {grid.reference!r} is not a method of the grid; methods: "
            f"{', '.join(methods)} (set `reference:` to one of them)"
        )
    return grid


# Config keys the grid sets per cell, and where a grid file sets them.
GRID_KEYS = {
    "dataset": "datasets",
    "descriptor": "descriptors",
    "sampler": "samplers",
    "seed": "seeds",
    "label": "samplers (as a method's label)",
    "sampler_params": "samplers (as a method's params)",
}


def _check_one_place(grid: GridSpec, where: str) -> None:
    """Refuse a key set in two places: the later one would silently win while labels show the other."""
    for key in grid.base:
        if key in GRID_KEYS and key != "sampler_params":
            raise InputError(
                f"{where}: base: {key!r} is set by the grid per cell; list it under `{GRID_KEYS[key]}:` instead"
            )
    if not isinstance(grid.base.get("sampler_params", {}), Mapping):
        raise InputError(f"{where}: base: sampler_params must be a mapping of sampler parameters")
    for key in grid.parameters:
        if key in GRID_KEYS:
            raise InputError(
                f"{where}: parameters: {key!r} is set by the grid per cell; list it under `{GRID_KEYS[key]}:` instead"
            )
        name = key.removeprefix("sampler.")
        for spec in grid.samplers:
            for part in ("sweep", "params"):
                if name in getattr(spec, part):
                    raise InputError(
                        f"{where}: {key!r} is set both in `parameters` and in the `{part}` of method "
                        f"{spec.label or spec.sampler!r}; set it in one place"
                    )


def _check_base_sampler_params(grid: GridSpec, where: str) -> None:
    """A base sampler parameter that no method's sampler takes is a typo, not a setting."""
    from msa_slam.sampling.registry import sampler_parameters

    taken = {k for spec in grid.samplers for k in sampler_parameters(spec.sampler)}
    unused = sorted(set(grid.base.get("sampler_params") or {}) - taken)
    if unused:
        raise InputError(
            f"{where}: base: sampler_params {', '.join(unused)}: no method's sampler takes "
            f"{'them' if len(unused) > 1 else 'it'} (samplers: "
            f"{', '.join(dict.fromkeys(s.sampler for s in grid.samplers))})"
        )


def check_datasets(grid: GridSpec, where: str = "grid", cells: Sequence[Cell] = ()) -> None:
    """Refuse a missing dataset folder, an unknown simulated name or (for the `cells`' simulated datasets) a
    selection beyond the sequence or options of recordings (--loader, --topic, --sequence) before any cell runs
    (and before the result folder is made), as `run` and `online` would in their first step; nothing is
    simulated here."""
    from msa_slam.datasets import SourceOptions
    from msa_slam.sources import check_selection, parse_spec

    specs = dict.fromkeys(seeded(d, seed) for d in grid.datasets for seed in grid.seeds)
    selections = dict.fromkeys(
        (c.config["dataset"], c.config.get("dataset_kind", "auto"), tuple(sorted(c.config["source"].items())))
        for c in cells
        if "source" in c.config
    )
    try:
        for spec in specs:
            parse_spec(spec)
        for spec, kind, source in selections:
            check_selection(spec, kind, SourceOptions(**dict(source)))
    except InputError as exc:
        message = str(exc) if str(exc).startswith("dataset ") else f"dataset {spec!r}: {exc}"
        raise InputError(f"{where}: {message}") from None


def load_grid(path: str | os.PathLike) -> GridSpec:
    """Read a grid YAML file, or a shipped preset by name (table2, ablation, distance_bounds, tiny)."""
    path = Path(path)
    if not path.is_file() and (GRID_DIR / f"{path}.yaml").is_file():
        path = GRID_DIR / f"{path}.yaml"
    if not path.is_file():
        presets = ", ".join(sorted(p.stem for p in GRID_DIR.glob("*.yaml")))
        raise InputError(f"{path}: grid file not found (shipped presets: {presets})")
    return parse_grid(read_yaml(path), str(path))


def slug(text: str) -> str:
    """`text` as a short file-name-safe word (cell ids, figure names)."""
    return re.sub(r"[^A-Za-z0-9=.+-]+", "_", text).strip("_")[:60]


def _config_for(
    grid: GridSpec,
    dataset: str,
    descriptor: str,
    sampler: str,
    params: dict[str, Any],
    parameters: dict[str, Any],
    seed: int,
    label: str,
    where: str,
) -> dict[str, Any]:
    from msa_slam.pipeline.config import apply_online_params, apply_params, make_config

    data = {
        **grid.base,
        "dataset": seeded(dataset, seed),
        "descriptor": descriptor,
        "sampler": sampler,
        "sampler_params": params,
        "label": label,
    }
    overrides = [f"{k}={json.dumps(v)}" for k, v in parameters.items()]
    try:
        if grid.pipeline == "online":
            return apply_online_params({**data, "seed": seed}, overrides).dump()
        return apply_params(make_config(data), overrides).dump()
    except InputError as exc:
        raise InputError(f"{where}: cell {label!r} on {dataset!r}: {exc}") from None


def expand(grid: GridSpec, where: str = "grid") -> list[Cell]:
    """All cells of the grid in a stable order; each config validated (its sampler's typed parameters included)."""
    methods = grid.methods(where)
    if grid.pipeline == "batch" and len(grid.seeds) > 1:
        same = next((d for d in grid.datasets if SEED not in d), None)
        if same is not None:
            raise InputError(
                f"{where}: seeds {grid.seeds} but dataset {same!r} has no {{seed}}: every seed would "
                "run the same cell (a batch run takes its seed from the dataset)"
            )
    keys = list(grid.parameters)
    cells: list[Cell] = []
    for dataset, descriptor, (label, sampler, params, swept), values, seed in itertools.product(
        grid.datasets, grid.descriptors, methods, itertools.product(*(grid.parameters[k] for k in keys)), grid.seeds
    ):
        parameters = dict(zip(keys, values))
        config = _config_for(grid, dataset, descriptor, sampler, params, parameters, seed, label, where)
        digest = hashlib.sha256(
            json.dumps({"pipeline": grid.pipeline, "config": config}, sort_keys=True, default=str).encode()
        ).hexdigest()[:10]
        name = slug(
            f"{dataset.split(',')[0]}-{descriptor}-{label}"
            + "".join(f"-{k}={v}" for k, v in parameters.items())
            + f"-s{seed}"
        )
        cells.append(
            Cell(
                id=f"{name}-{digest}",
                index=len(cells),
                pipeline=grid.pipeline,
                dataset=dataset,
                descriptor=descriptor,
                method=label,
                sampler=sampler,
                swept=swept,
                parameters=parameters,
                seed=seed,
                config=config,
            )
        )
    digests = [c.id.rsplit("-", 1)[1] for c in cells]  # the config hash: names differ by seed even when configs do not
    if len(set(digests)) != len(digests):
        raise InputError(f"{where}: some cells have identical configs (repeated datasets, seeds or methods)")
    return cells
