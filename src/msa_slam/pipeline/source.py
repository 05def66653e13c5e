"""Resolve a dataset argument: a sequence folder, `sim:NAME[,field=value...]` built by msa_slam.sim, or (as
a frame source for the online pipeline) `live:NAME` simulated in memory."""

from __future__ import annotations

import os
from pathlib import Path

import yaml

from msa_slam.datasets import ScanSequence, open_dataset
from msa_slam.errors import InputError
from msa_slam.types import FrameSource

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
        path = Path(spec).expanduser()
        if not path.exists():
            raise InputError(f"dataset {spec!r}: folder not found (give a sequence folder or sim:NAME)")
        return path
    from msa_slam.sim import DEFAULT_CONFIGS, TRAJECTORY_NAMES, default_sequence, make_config, simulate_sequence

    items = spec[len(SIM_PREFIX):].split(",")
    name, fields = ("", items) if "=" in items[0] else (items[0], items[1:])
    if name in DEFAULT_CONFIGS and not fields:
        return default_sequence(name, cache_dir=cache_dir, progress=progress)
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
    return simulate_sequence(make_config(**base), cache_dir=cache_dir, progress=progress)


def open_sequence(spec: str, kind: str = "auto", cache_dir: str | os.PathLike | None = None,
                  progress: bool = False) -> ScanSequence:
    """The scan sequence of `spec`; the batch experiment needs its ground-truth poses."""
    sequence = open_dataset(resolve_dataset(spec, cache_dir, progress), kind=kind)
    if sequence.gt_poses is None:
        raise InputError(f"dataset {spec!r}: no ground-truth poses found (poses.txt, ../../poses/NN.txt or the "
                         "dataset's ground-truth file); the batch experiment needs them for oracle loops and ATE")
    if len(sequence) < 3:
        raise InputError(f"dataset {spec!r}: {len(sequence)} scans; the batch experiment needs at least 3")
    return sequence


def open_source(spec: str, kind: str = "auto", cache_dir: str | os.PathLike | None = None,
                progress: bool = False) -> FrameSource:
    """The frame source named by `spec` (folder, sim:NAME or live:NAME); it must have ground truth."""
    from msa_slam.sim.live import LIVE_PREFIX, live_source

    if spec.startswith(LIVE_PREFIX):
        return live_source(spec)
    sequence = open_sequence(spec, kind, cache_dir, progress)
    return FrameSource(sequence.name, sequence.gt_poses, lambda: iter(sequence), sequence.path)
