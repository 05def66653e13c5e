"""The scans a dataset spec names: its sequence folder (a sim: sequence simulated on first use and cached), its
ScanSequence (the part a run's source options select), or a run's FrameSource (live: simulated as it is read).
What the options select is checked against the spec before anything is simulated or read."""

from __future__ import annotations

import os
from pathlib import Path

from msa_slam.datasets import ParsedScans, ScanSequence, SourceOptions, open_source_options
from msa_slam.datasets.sequences import selected_count
from msa_slam.errors import InputError
from msa_slam.io.cache import cache_root
from msa_slam.sources.spec import SourceSpec, parse_spec
from msa_slam.types import FrameSource

# SourceOptions' fields as run and online name them
RECORDING_FLAGS = {
    "topic": "--topic",
    "gt": "--gt",
    "gt_format": "--gt-format",
    "sequence": "--sequence",
    "first": "--first",
    "jump": "--jump",
    "frames": "-n",
}
SIMULATED_FLAGS = ("topic", "sequence")  # what a sim: sequence, one folder of scans, has no use for


def _spec(spec: str | SourceSpec) -> SourceSpec:
    return spec if isinstance(spec, SourceSpec) else parse_spec(spec)


def resolve_dataset(spec: str | SourceSpec, cache_dir: str | os.PathLike | None = None, progress: bool = False) -> Path:
    """Folder (or bag) of the sequence `spec` names; a sim: sequence is simulated on first use and cached."""
    spec = _spec(spec)
    if spec.kind == "live":
        raise InputError(
            f"dataset {spec.text!r}: a live: source is simulated as `msa-slam online` reads it and has "
            "no folder; give sim:... for a sequence cached on disk"
        )
    if spec.path is not None:
        return spec.path
    from msa_slam.sim import simulate_sequence

    return simulate_sequence(spec.simulation, cache_dir=cache_dir, progress=progress)


def open_sequence(
    spec: str | SourceSpec,
    kind: str = "auto",
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
    source: SourceOptions | None = None,
    mode: str = "realistic",
    keep_parsed: bool = False,
) -> ScanSequence:
    """The scan sequence of `spec` (the part `source` selects); ground truth is optional, but the oracle
    `mode` verifies loops by ground-truth distance and so refuses a sequence without it. `keep_parsed`: for a
    run that reads its scans more than once, text scans are parsed once and kept as binary in the cache root
    (datasets.parsed)."""
    spec, source = _spec(spec), source or SourceOptions()
    check_selection(spec, kind, source)
    parsed = ParsedScans(cache_root(cache_dir)) if keep_parsed else None
    sequence = open_source_options(resolve_dataset(spec, cache_dir, progress), kind, source, parsed)
    if sequence.gt_poses is None and mode == "oracle":
        raise InputError(
            f"dataset {spec.text!r}: no ground-truth poses, which the oracle mode needs (it verifies "
            "only loops that ground truth confirms); use --mode realistic, or give ground truth with "
            "--gt FILE (KITTI or TUM, LiDAR frame)"
        )
    _check_enough_scans(spec, len(sequence))
    return sequence


def open_source(
    spec: str | SourceSpec,
    kind: str = "auto",
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
    source: SourceOptions | None = None,
    mode: str = "realistic",
) -> FrameSource:
    """The frame source `spec` names (folder, bag, sim: or live:); see open_sequence."""
    spec = _spec(spec)
    if spec.kind == "live":
        from msa_slam.sim.live import live_source

        check_selection(spec, kind, source or SourceOptions())
        return live_source(spec.simulation, spec.laps, spec.label)
    sequence = open_sequence(spec, kind, cache_dir, progress, source, mode)
    return FrameSource(
        sequence.name,
        sequence.gt_poses,
        lambda: iter(sequence),
        sequence,
        len(sequence),
        sequence.times_known,
        sequence.point_times,
    )


def check_selection(spec: str | SourceSpec, kind: str, source: SourceOptions) -> None:
    """For a simulated `spec`, before anything is simulated: the recording options it has no use for (a live:
    source: every one; a sim: sequence: the loader `kind`, --topic, --sequence) and, for sim:, what `source`
    selects (--first/--jump/-n, from the sequence's frame count). A recording's selection is checked when it is
    opened (ScanSequence.select)."""
    spec = _spec(spec)
    if spec.kind == "live":
        _refuse_recording_options(spec, kind, source, tuple(RECORDING_FLAGS))
    elif spec.kind == "sim":
        _refuse_recording_options(spec, kind, source, SIMULATED_FLAGS)
        _check_enough_scans(
            spec,
            selected_count(
                spec.simulation.frame_count(), source.first, source.jump, source.frames, f"dataset {spec.text!r}"
            ),
        )


def _check_enough_scans(spec: SourceSpec, scans: int) -> None:
    if scans < 3:
        raise InputError(
            f"dataset {spec.text!r}: {scans} scan{'' if scans == 1 else 's'} selected; a run needs at least 3"
        )


def _refuse_recording_options(spec: SourceSpec, kind: str, source: SourceOptions, fields: tuple[str, ...]) -> None:
    """Options that read or select part of a recording but do not apply to a simulated `spec` (`fields` of the
    source options, and a loader) are refused rather than ignored or failing on the simulation's cache folder."""
    default = SourceOptions()
    simulated = spec.kind == "sim"
    loader = kind not in ("auto", "kitti") if simulated else kind != "auto"  # a sim: sequence has KITTI's layout
    given = (["--loader"] if loader else []) + [
        RECORDING_FLAGS[field] for field in fields if getattr(source, field) != getattr(default, field)
    ]
    if not given:
        return
    verb = "applies" if len(given) == 1 else "apply"
    if simulated:
        raise InputError(
            f"dataset {spec.text!r}: {', '.join(given)} {verb} to recordings; a sim: dataset is one "
            "simulated sequence in KITTI's layout (choose its frames with --first/--jump/-n or start=, "
            "end=, stride= in the spec)"
        )
    raise InputError(
        f"dataset {spec.text!r}: {', '.join(given)} {verb} to recordings, not to a live: source "
        "(simulated as it runs); choose its frames in the spec (start=, end=, stride=, e.g. "
        "live:figure-eight,start=100,stride=2) or cap them with -p max_frames=N"
    )
