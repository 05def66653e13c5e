"""Resolve a dataset argument: a sequence folder or bag, `sim:NAME[,field=value...]` built by msa_slam.sim, or (as
a frame source for the online pipeline) `live:NAME` simulated in memory."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import yaml

from msa_slam.datasets import ParsedScans, ScanSequence, SourceOptions, open_source_options
from msa_slam.datasets.sequences import selected_count
from msa_slam.errors import InputError
from msa_slam.io.cache import cache_root
from msa_slam.types import FrameSource

if TYPE_CHECKING:
    from msa_slam.sim import SimConfig

SIM_PREFIX = "sim:"
PATH_FIELDS = ("trajectory", "times", "calib")  # taken verbatim: a file named 1e3 stays a path


def resolve_dataset(spec: str, cache_dir: str | os.PathLike | None = None, progress: bool = False) -> Path:
    """Folder of the sequence named by `spec`; simulated sequences are generated on first use and cached.

    `sim:demo` / `sim:test` are the simulator's embedded defaults; `sim:TRAJECTORY` (e.g. sim:kitti-05)
    simulates that trajectory with the simulator's defaults, overridable as `sim:kitti-05,stride=3,end=900`.
    A spec whose first item is a field (`sim:trajectory=/data/poses.txt,times=/data/times.txt,stride=2`)
    starts from the simulator's defaults; `trajectory=` takes a shipped name or a pose file (KITTI or TUM;
    with `calib=` a KITTI calib.txt for cam0 poses). Items are split at commas, so paths cannot hold one.
    """
    if not spec.startswith(SIM_PREFIX):
        return _existing_path(spec)
    from msa_slam.sim import simulate_sequence

    return simulate_sequence(sim_config(spec), cache_dir=cache_dir, progress=progress)


def check_dataset(spec: str) -> None:
    """What resolve_dataset and the live source check before any work, without simulating or reading: that a
    folder or bag exists, that a sim: or live: spec names a known sequence with valid fields."""
    from msa_slam.sim.live import LIVE_PREFIX, live_settings

    if spec.startswith(LIVE_PREFIX):
        live_settings(spec)
    elif spec.startswith(SIM_PREFIX):
        sim_settings(spec)
    else:
        _existing_path(spec)


def _existing_path(spec: str) -> Path:
    path = Path(spec).expanduser()
    if not path.exists():
        raise InputError(f"dataset {spec!r}: not found (give a sequence folder, a bag or sim:NAME)")
    return path


def sim_settings(spec: str) -> tuple[str, "SimConfig | None"]:
    """(default name, None) for an embedded default as it is (`sim:demo`), else ("", its validated SimConfig)."""
    from msa_slam.sim import DEFAULT_CONFIGS, TRAJECTORY_NAMES, make_config

    items = spec[len(SIM_PREFIX):].split(",")
    name, fields = ("", items) if "=" in items[0] else (items[0].strip(), items[1:])
    if not name and not fields:  # e.g. sim:$SEQUENCE with the variable unset
        raise InputError(f"dataset {spec!r}: names no simulated sequence; give sim:NAME (one of "
                         f"{', '.join([*DEFAULT_CONFIGS, *TRAJECTORY_NAMES])}) or fields (sim:trajectory=FILE,...)")
    if name in DEFAULT_CONFIGS and not fields:
        return name, None
    if name in DEFAULT_CONFIGS:
        base = DEFAULT_CONFIGS[name].model_dump()
    elif name in TRAJECTORY_NAMES:
        base = {"trajectory": name}
    elif not name:
        base = {}
    else:
        raise InputError(f"dataset {spec!r}: unknown simulated sequence {name!r}; choose one of "
                         f"{', '.join([*DEFAULT_CONFIGS, *TRAJECTORY_NAMES])}, or give fields only "
                         "(sim:trajectory=/path/poses.txt,...)")
    for item in fields:
        key, sep, raw = item.partition("=")
        if not sep:
            raise InputError(f"dataset {spec!r}: expected field=value, got {item!r}")
        value = yaml.safe_load(raw)
        base[key.strip()] = raw.strip() if key.strip() in PATH_FIELDS else value
    return "", make_config(**base)


def sim_config(spec: str) -> "SimConfig":
    """The validated SimConfig of a `sim:` spec, an embedded default's included."""
    from msa_slam.sim import DEFAULT_CONFIGS

    default, config = sim_settings(spec)
    return DEFAULT_CONFIGS[default] if config is None else config


def open_sequence(spec: str, kind: str = "auto", cache_dir: str | os.PathLike | None = None,
                  progress: bool = False, source: SourceOptions | None = None,
                  mode: str = "realistic", keep_parsed: bool = False) -> ScanSequence:
    """The scan sequence of `spec` (the part `source` selects); ground truth is optional, but the oracle
    `mode` verifies loops by ground-truth distance and so refuses a sequence without it. `keep_parsed`: for a
    run that reads its scans more than once, text scans are parsed once and kept as binary in the cache root
    (datasets.parsed)."""
    source = source or SourceOptions()
    check_simulated_source(spec, kind, source)
    parsed = ParsedScans(cache_root(cache_dir)) if keep_parsed else None
    sequence = open_source_options(resolve_dataset(spec, cache_dir, progress), kind, source, parsed)
    if sequence.gt_poses is None and mode == "oracle":
        raise InputError(f"dataset {spec!r}: no ground-truth poses, which the oracle mode needs (it verifies only "
                         "loops that ground truth confirms); use --mode realistic, or give ground truth with --gt "
                         "FILE (KITTI or TUM, LiDAR frame)")
    _check_enough_scans(spec, len(sequence))
    return sequence


def check_simulated_source(spec: str, kind: str, source: SourceOptions) -> None:
    """For a `sim:` spec, before anything is simulated: the recording options it has no use for (the loader
    `kind`, --topic, --sequence) and what `source` selects (--first/--jump/-n, from the sequence's frame count);
    other datasets' selections are checked when they are opened (ScanSequence.select)."""
    if spec.startswith(SIM_PREFIX):
        _refuse_recording_options(spec, kind, source, SIMULATED_FLAGS)
        _check_enough_scans(spec, selected_count(sim_config(spec).frame_count(), source.first, source.jump,
                                                 source.frames, f"dataset {spec!r}"))


def _check_enough_scans(spec: str, scans: int) -> None:
    if scans < 3:
        raise InputError(f"dataset {spec!r}: {scans} scan{'' if scans == 1 else 's'} selected; a run needs at least 3")


def open_source(spec: str, kind: str = "auto", cache_dir: str | os.PathLike | None = None,
                progress: bool = False, source: SourceOptions | None = None, mode: str = "realistic") -> FrameSource:
    """The frame source named by `spec` (folder, bag, sim:NAME or live:NAME); see open_sequence."""
    from msa_slam.sim.live import LIVE_PREFIX, live_source

    if spec.startswith(LIVE_PREFIX):
        _refuse_recording_options(spec, kind, source or SourceOptions())
        return live_source(spec)
    sequence = open_sequence(spec, kind, cache_dir, progress, source, mode)
    return FrameSource(sequence.name, sequence.gt_poses, lambda: iter(sequence), sequence, len(sequence),
                       sequence.times_known, sequence.point_times)


# SourceOptions' fields as run and online name them
RECORDING_FLAGS = {"topic": "--topic", "gt": "--gt", "gt_format": "--gt-format", "sequence": "--sequence",
                   "first": "--first", "jump": "--jump", "frames": "-n"}
SIMULATED_FLAGS = ("topic", "sequence")  # what a sim: sequence, one folder of scans, has no use for


def _refuse_recording_options(spec: str, kind: str, source: SourceOptions,
                              fields: tuple[str, ...] = tuple(RECORDING_FLAGS)) -> None:
    """Options that read or select part of a recording but do not apply to a simulated `spec` (a live: source:
    every one; a sim: sequence: `fields` and --loader) are refused before anything is simulated, rather than
    ignored or failing on the simulation's cache folder."""
    default = SourceOptions()
    simulated = spec.startswith(SIM_PREFIX)
    loader = kind not in ("auto", "kitti") if simulated else kind != "auto"  # a sim: sequence has KITTI's layout
    given = (["--loader"] if loader else []) + [RECORDING_FLAGS[field] for field in fields
                                                if getattr(source, field) != getattr(default, field)]
    if not given:
        return
    verb = "applies" if len(given) == 1 else "apply"
    if simulated:
        raise InputError(f"dataset {spec!r}: {', '.join(given)} {verb} to recordings; a sim: dataset is one "
                         "simulated sequence in KITTI's layout (choose its frames with --first/--jump/-n or start=, "
                         "end=, stride= in the spec)")
    raise InputError(f"dataset {spec!r}: {', '.join(given)} {verb} to recordings, not to a live: source "
                     "(simulated as it runs); choose its frames in the spec (start=, end=, stride=, e.g. "
                     "live:figure-eight,start=100,stride=2) or cap them with -p max_frames=N")
