"""A run's configuration (pydantic): every knob of the paper's section V-A protocol, composed of the stages'
own configs (`verifier`: registration.VerifierConfig, `graph`: backend.GraphConfig); the online protocol
extends it (OnlineConfig: the same loop, verifier and graph knobs plus what only a frame-by-frame run needs: where
keyframe clouds live, iSAM2 iterations, sensor rate, noise seed).

Unknown keys are an error that lists the valid ones, so a typo never silently runs the default.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, Literal, TypeVar, get_args

from pydantic import BaseModel, Field, TypeAdapter, ValidationError, field_serializer, field_validator, model_validator
from pydantic_core import PydanticCustomError

from msa_slam.backend.graph_config import GraphConfig
from msa_slam.config import StageConfig, check_partial
from msa_slam.datasets.options import SourceOptions
from msa_slam.errors import InputError
from msa_slam.io.params import parse_key_value
from msa_slam.io.yaml_file import read_yaml
from msa_slam.registration.verify import VerifierConfig
from msa_slam.sampling.params import TAG, SamplerParams, explain
from msa_slam.sampling.registry import SAMPLERS, SamplerChoice, check_sampler_params, sampler_parameters


class RunConfig(StageConfig):
    """One run: dataset, odometry, descriptor, sampler, loop closing, verification, graph.

    `dataset` is a sequence folder (KITTI layout, scan folder, ...) or bag, read by the loader `dataset_kind`
    (auto: from the layout; msa_slam.datasets.LOADERS) with the `source` options (topic, ground truth, part
    of the recording), or `sim:NAME` (NAME = demo, test, or a simulator trajectory such as kitti-05,
    optionally with simulator fields: `sim:kitti-05,stride=3`).
    `sampler_params` are the parameters of `sampler`, a tagged union of the samplers' typed models (the sampler's
    name its tag; sampling/params.py, sampling/registry.py): they are checked against that sampler when the config
    is built, and the config echoes them as given (config.yaml holds no defaults).
    `odometry` is "kiss" (KISS-ICP) or the path of a KITTI/TUM pose file (LiDAR frame, one pose per scan).
    Keyframes are sampled on `sample_on` poses (`flush` adds what MSA still holds at the end). A keyframe's
    loop candidates are older keyframes more than `min_frame_gap` frames and `min_travel_m` metres of
    odometry path back (a revisit, not a standstill) and not among the `exclude_recent` newest, with
    descriptor similarity >= `similarity_threshold` (best `top_k`). With `drift_check` on ("auto": in
    realistic mode only, where no ground truth vets candidates) a registered loop is also rejected when its
    correction of the odometry between its keyframes fails a chi-square test (quantile `drift_confidence`)
    against the odometry covariance accumulated along the path (graph.drift_*, the covariance the pose graph
    weights odometry with, grown as systematic drift beyond graph.drift_reference_m) widened `drift_gate` times
    in sigma (1: as is), plus the loop's covariance and a slack of `drift_slack_m` / `drift_slack_deg`
    (slam/loop_closing.py).
    `loop_radius` (3 m) defines a true loop (oracle verification, distant loops and the PR curve) and the
    translation error of a false loop's measured pose (evaluation/loops.py).

    `loop_detector` chooses what finds loop candidates (samplers always use the front end's per-scan
    descriptors): "scan" the front end's descriptor of the keyframe's scan (the paper); "local-map" Scan
    Context of the keyframe's local map, the voxel-merged scans of the last `local_map_m` metres of odometry
    path (slam/local_map.py), which then is also the keyframe's cloud for verification; "map-closures" the
    MapClosures package (Gupta et al., ICRA 2024: density images of the local maps, ORB features, RANSAC;
    `pip install --no-deps map_closures==2.2.0`). `loop_protocol` chooses how candidates are accepted:
    "paper" takes matches at or above `similarity_threshold` (best `top_k`) and registers them from the
    descriptor's yaw; "verified" takes the best `verified_top_k` above the low floor
    `verified_min_similarity` and lets registration decide, from the detector's yaw (Scan Context) or pose
    (MapClosures) plus a coarse translation search, so no odometry prior is needed; "auto" (the default): paper
    in oracle mode, verified in realistic mode (slam/loop_closing.py). Oracle mode is the paper's protocol, so it
    keeps the paper's acceptance; in realistic mode the verified protocol closes revisits the paper's threshold
    misses (a street driven back the other way, the revisits of simulated KITTI-00 once keyframes are sparse) with
    no false loop where measured, at several times the paper protocol's back-end time (docs/performance.md).
    """

    dataset: str
    dataset_kind: str = "auto"
    source: SourceOptions = Field(default_factory=SourceOptions)
    odometry: str = "kiss"
    odometry_params: dict[str, Any] = Field(default_factory=dict)
    descriptor: str = "sc"
    descriptor_params: dict[str, Any] = Field(default_factory=dict)
    sampler: str = "msa"
    sampler_params: SamplerChoice
    sample_on: Literal["odometry", "gt"] = "odometry"
    flush: bool = True
    mode: Literal["oracle", "realistic"] = "oracle"
    similarity_threshold: float = Field(0.8, ge=0, le=1)
    min_frame_gap: int = Field(50, ge=0)
    exclude_recent: int = Field(10, ge=0)
    top_k: int = Field(1, ge=1)
    loop_radius: float = Field(3.0, gt=0)
    min_travel_m: float = Field(30.0, ge=0)
    drift_check: Literal["auto", "on", "off"] = "auto"
    drift_gate: float = Field(1.0, gt=0)
    drift_confidence: float = Field(0.999, gt=0, lt=1)
    drift_slack_m: float = Field(1.0, ge=0)
    drift_slack_deg: float = Field(2.0, ge=0)
    loop_detector: Literal["scan", "local-map", "map-closures"] = "scan"
    loop_protocol: Literal["auto", "paper", "verified"] = "auto"
    verified_top_k: int = Field(3, ge=1)
    verified_min_similarity: float = Field(0.3, ge=0, le=1)
    local_map_m: float = Field(40.0, gt=0)
    verifier: VerifierConfig = Field(default_factory=VerifierConfig)
    graph: GraphConfig = Field(default_factory=GraphConfig)
    cache_dir: str | None = None
    label: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _tag_sampler_params(cls, data: Any) -> Any:
        """`sampler` chooses the model of `sampler_params` (the tagged union's tag), so they are checked against
        the sampler that will run, when the config is built."""
        if isinstance(data, Mapping):
            sampler = data.get("sampler", cls.model_fields["sampler"].default)
            params = data.get("sampler_params", {})
            if isinstance(params, SamplerParams) and params.NAME == sampler:
                return data  # validated already (a copy, an assignment to another field)
            if isinstance(params, Mapping) and TAG in params:
                raise PydanticCustomError(
                    "sampler_choice",
                    f"sampler_params: {TAG!r} is not a sampler parameter; "
                    "choose the sampler with the config's `sampler` (-p sampler=NAME)",
                )
            if isinstance(params, Mapping):
                data = {**data, "sampler_params": {TAG: sampler, **params}}
        return data

    @model_validator(mode="after")
    def _sampler_checked(self) -> RunConfig:
        if not isinstance(self.sampler_params, SamplerParams):  # `sampler` assigned alone: its parameters unchecked
            raise PydanticCustomError(
                "sampler_choice",
                f"sampler {self.sampler!r} assigned without its parameters; build a new config with both (make_config)",
            )
        return self

    @field_validator("descriptor_params", "odometry_params")
    @classmethod
    def _finite(cls, params: dict[str, Any]) -> dict[str, Any]:
        """Free-form parameters (their stage checks the names): finite numbers only (YAML would save NaN as null)."""
        found = non_finite(params, "")
        if found is not None:
            raise PydanticCustomError("finite_number", f"{found} is not allowed; expected a finite number")
        return params

    @field_serializer("sampler_params")
    def _given_params(self, params: SamplerParams) -> dict[str, Any]:
        """The parameters as given (the config's echo: config.yaml, metrics.json), not their defaults."""
        return dict(params)

    @classmethod
    def explain_error(cls, error: Mapping[str, Any]) -> str | None:
        """A sampler parameter's error in the sampler's words (config.problem); None for the other fields."""
        loc = tuple(error["loc"])
        if error["type"] == "sampler_choice":
            return str(error["msg"])
        if not loc or loc[0] != "sampler_params":
            return None
        if error["type"] == "union_tag_invalid":
            return f"unknown sampler {error['ctx']['tag']!r}; available: {', '.join(SAMPLERS)}"
        if len(loc) > 1 and loc[1] in SAMPLERS:
            return explain(SAMPLERS[str(loc[1])].Params, {**error, "loc": loc[2:]})
        return None

    @property
    def name(self) -> str:
        """Label of the run in tables (the sampler name unless given)."""
        return self.label or self.sampler

    def dump(self) -> dict[str, Any]:
        return self.model_dump(mode="json")


def make_config(data: Mapping[str, Any] | None = None, **overrides: Any) -> RunConfig:
    """A validated RunConfig from a mapping plus keyword overrides; problems become one InputError."""
    return RunConfig(**{**(dict(data) if data else {}), **overrides})


class OnlineConfig(RunConfig):
    """One online run (the paper's section V-B protocol).

    `dataset` also accepts `live:NAME[,field=value...,laps=K]`: scans simulated in memory as the run
    needs them (no files), K passes over the trajectory driven forth and back (msa_slam.sim.live).
    `odometry` also accepts "gt-noise": ground-truth motions with random noise (odometry_params
    translation_noise, rotation_noise_deg; seeded by `seed`), for long runs where KISS-ICP would dominate.
    `cloud_store="disk"` keeps downsampled keyframe clouds as .npy files (memory-mapped when read) instead of
    in RAM, in a private folder under `store_dir` (default: the system temporary folder) that is removed when
    the run ends; pick a `store_dir` on a real disk when the temporary folder is in RAM (tmpfs).
    `sensor_rate_hz` is the data's frame rate for the real-time factor only while the frames' timestamps span
    no time (fewer than two frames) or the frames have none (a folder without times.txt or TUM poses);
    otherwise the timestamps give it.
    KISS-ICP runs on every core for a `live:` source and on one thread for recorded data (bit-reproducible);
    `odometry_params: {num_threads: N}` wins (pipeline.live.with_odometry_threads).
    """

    SECTION: ClassVar[str] = "online config"

    cloud_store: Literal["memory", "disk"] = "memory"
    store_dir: str | None = None
    update_iterations: int = Field(2, ge=0)
    sensor_rate_hz: float = Field(10.0, gt=0)
    max_frames: int | None = Field(None, ge=3)
    seed: int = 0


NO_TIMESTAMPS = "sensor_rate_hz (the frames have no timestamps)"  # frame_rate_from without them
NOT_REPRODUCIBLE = "not bit-reproducible (multi-threaded odometry)"  # a run whose KISS-ICP used several threads


def make_online_config(data: Mapping[str, Any] | None = None, **overrides: Any) -> OnlineConfig:
    """A validated OnlineConfig from a mapping plus keyword overrides; problems become one InputError."""
    return OnlineConfig(**{**(dict(data) if data else {}), **overrides})


def apply_online_params(data: Mapping[str, Any], params: list[str]) -> OnlineConfig:
    """`key=value` overrides (YAML values) on an online config mapping: apply_params on its OnlineConfig."""
    return apply_params(make_online_config(data), params)


def non_finite(value: Any, where: str) -> str | None:
    """`where.key=value` (`key=value` for an empty `where`) of the first NaN or infinity in a stage's free-form
    parameters (YAML would save it as null), or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return f"{where}={value!r}"
    items = (
        value.items() if isinstance(value, Mapping) else enumerate(value) if isinstance(value, (list, tuple)) else ()
    )
    for key, item in items:
        found = non_finite(
            item, (f"{where}.{key}" if where else str(key)) if isinstance(value, Mapping) else f"{where}[{key}]"
        )
        if found is not None:
            return found
    return None


def check_descriptor(descriptor: str, params: Mapping[str, Any]) -> None:
    """The descriptor's name and the file it needs (OverlapTransformer's weights, precomputed descriptors),
    reported before any scan is simulated (the descriptor itself is built after the dataset is opened). Not
    in make_config: the CLI makes a config from its options before the -p overrides add those files."""
    from msa_slam.descriptors.registry import DESCRIPTOR_NAMES

    name = str(descriptor).lower()
    if name not in DESCRIPTOR_NAMES:
        raise InputError(
            f"config: descriptor: unknown name {descriptor!r}; choose one of {', '.join(DESCRIPTOR_NAMES)}"
        )
    if name == "precomputed" and "path" not in params:
        raise InputError(
            "config: descriptor 'precomputed' needs its descriptor file, -p descriptor.path=FILE.npy "
            "(one descriptor per scan, e.g. a result folder's descriptors.npy)"
        )
    if name not in OT_NAMES:
        return
    from msa_slam.descriptors.overlap_transformer import WEIGHTS_HINT

    if "weights" not in params:
        raise InputError(f"config: descriptor {descriptor!r} needs its weights file, -p weights=FILE: {WEIGHTS_HINT}")
    if not Path(str(params["weights"])).is_file():
        raise InputError(
            f"config: descriptor {descriptor!r}: weights file not found: {params['weights']}; expected {WEIGHTS_HINT}"
        )


def load_config(path: str | os.PathLike) -> RunConfig:
    """Read a whole YAML config file (the `config.yaml` of a result folder works as input)."""
    return make_config(read_config_file(path))


def read_config_file(path: str | os.PathLike, model: type[RunConfig] = RunConfig) -> dict[str, Any]:
    """A YAML config file as a mapping: a command's --config, which its options complete (a file without
    `dataset` is fine with --dataset), so the whole config is validated only once they are in.

    What the file holds is checked here already, against `model` (OnlineConfig for `online`): an unknown or
    wrongly typed key, a NaN parameter or one the file's sampler does not take is refused naming the file,
    which the error of the merged config could not tell apart from the options. Sampler parameters in a
    file that names no sampler wait for the merge (the --sampler option decides whose they are).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: config file not found")
    data = read_yaml(path) or {}
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping of config keys, got {type(data).__name__}")
    check_partial(
        model, data if "sampler" in data else {k: v for k, v in data.items() if k != "sampler_params"}, str(path)
    )
    found = None if "sampler" in data else non_finite(data.get("sampler_params"), "sampler_params")
    if found is not None:  # whoever's parameters they are, a NaN is none's
        raise InputError(f"{path}: {found} is not allowed; expected a finite number")
    return data


C = TypeVar("C", bound=RunConfig)
_SECTIONS = {"sampler": "sampler_params", "descriptor": "descriptor_params", "odometry": "odometry_params"}


def apply_params(config: C, params: list[str]) -> C:
    """Apply `key=value` overrides (values parsed as YAML).

    Keys: a config field (`similarity_threshold=0.7`), a section field (`verifier.max_residual=0.2`,
    `graph.robust=cauchy`), a stage parameter (`sampler.lambda_u=5`, `descriptor.n_sector=60`,
    `odometry.max_range=80`; also by the config key, `sampler_params.lambda_u=5`), a bare sampler parameter
    (`lambda_u=5`), or the bare OverlapTransformer weights file (`weights=FILE`, as `--descriptor ot -p weights=FILE`
    reads in the docs).
    The result is a command's final config, so the descriptor (name, weights or descriptor file) is checked here.
    """
    model = type(config)  # RunConfig, or OnlineConfig
    config = model(**apply_overrides(config.dump(), params, model))
    check_descriptor(config.descriptor, config.descriptor_params)
    return config


def apply_overrides(data: dict, params: list[str], model: type[BaseModel]) -> dict:
    """The config mapping `data` (fields of `model`) with each `key=value` override applied.

    Bare keys that are no config field go to the sampler or the descriptor chosen after all overrides, so
    `-p weights=FILE -p descriptor=ot` and `-p descriptor=ot -p weights=FILE` mean the same."""
    data = dict(data)
    bare: list[tuple[str, Any]] = []
    for item in params:
        key, value = parse_key_value(item)
        head, dot, tail = key.partition(".")
        head = next((stage for stage, section in _SECTIONS.items() if section == head), head)  # sampler_params.x
        if dot and head in _SECTIONS:
            data[_SECTIONS[head]] = {**data[_SECTIONS[head]], tail: value}
        elif dot and head in ("verifier", "graph"):
            data[head] = {**data[head], tail: value}
        elif not dot and key in model.model_fields:
            _check_not_a_sampler_param(data.get("sampler"), key, value, model)
            data[key] = value
        elif not dot:
            bare.append((key, value))
        else:
            raise InputError(
                f"--param {key!r}: unknown section {head!r}; use one of {', '.join([*_SECTIONS, 'verifier', 'graph'])}"
            )
    for key, value in bare:
        section = _bare_key_section(data["sampler"], data["descriptor"], key, value, model)
        data[section] = {**data[section], key: value}
    return data


def _check_not_a_sampler_param(sampler: str | None, key: str, value: Any, model: type[BaseModel]) -> None:
    """A bare key naming both a config field and a sampler parameter (`mode`) sets the config field;
    a value that only the sampler accepts (`mode=fast`) is refused with the spelling that reaches it."""
    if sampler is None or key not in sampler_parameters(sampler):
        return
    annotation = model.model_fields[key].annotation
    assert annotation is not None, "every field of a config model is annotated"
    try:
        TypeAdapter(annotation).validate_python(value)
        return
    except ValidationError:
        pass
    try:
        check_sampler_params(sampler, {key: value})
    except InputError:
        return  # valid for neither: the config field's own error follows
    raise InputError(
        f"--param {key}={value}: `{key}` is the config's {key} ({_allowed(model, key)}); "
        f"for the {sampler} sampler's {key} write sampler.{key}={value}"
    )


def _allowed(model: type[BaseModel], key: str) -> str:
    args = get_args(model.model_fields[key].annotation)
    return ", ".join(map(str, args)) if args else str(model.model_fields[key].annotation)


def _bare_key_section(sampler: str, descriptor: str, key: str, value: Any, model: type[BaseModel]) -> str:
    """Where a bare key that is no config field goes: "sampler_params" for a parameter of `sampler`,
    "descriptor_params" for `weights` with the OverlapTransformer; else an InputError listing what exists."""
    known = sampler_parameters(sampler)
    if key in known:
        return "sampler_params"
    if key == "weights" and str(descriptor).lower() in OT_NAMES:
        return "descriptor_params"
    if key == "weights":
        raise InputError(
            f"--param weights={value}: the weights file is the OverlapTransformer's, but the "
            f"descriptor is {descriptor!r}; add --descriptor ot (or -p descriptor=ot)"
        )
    raise InputError(
        f"--param {key!r}: not a config key ({', '.join(model.model_fields)}), a parameter of "
        f"sampler {sampler!r} ({', '.join(known) or 'none'}) nor weights (of descriptor ot)"
    )


OT_NAMES = ("ot", "overlap_transformer")  # the descriptor that takes `weights`, also as a bare key (-p weights=FILE)
