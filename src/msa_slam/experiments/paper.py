"""The paper's evaluation as four shipped grids (paper-table1, paper-table2, paper-ablation, paper-bounds), the
simulated stand-ins for the datasets the simulator cannot be, and the `--quick` and `--seeds` variants of the grids.

The variants are derived from the shipped grids by code, so `--quick` runs the same grids (same methods, same
settings) on short prefixes: nothing is tuned for the quick run alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from msa_slam.errors import InputError
from msa_slam.experiments.grid import GridSpec, load_grid

PRESETS = ("paper-table1", "paper-table2", "paper-ablation", "paper-bounds")
QUICK_FRAMES = {"batch": 120, "online": 40}  # frames of each sequence's prefix under --quick
QUICK_DATASETS = {"batch": 2, "online": 1}  # the first datasets of a grid (KITTI-05 and -06; the long drive)
QUICK_LAPS = 3  # passes of a live: drive under --quick (the full Table II drive has ten)


@dataclass(frozen=True)
class StandIn:
    """Which paper column a simulated sequence plays, and why it was chosen."""

    column: str
    why: str


# Keyed by the simulated trajectory name (the first item of a sim:/live: spec).
STAND_INS: dict[str, StandIn] = {
    "kitti-05": StandIn("KITTI-05", "the shipped KITTI-05 ground truth, simulated with an HDL-64 (KITTI's sensor)"),
    "kitti-06": StandIn("KITTI-06", "the shipped KITTI-06 ground truth, simulated with an HDL-64"),
    "kitti-00": StandIn(
        "MulRan DCC",
        "a long urban drive with several revisits, seen by an OS1-64 (MulRan's "
        "sensor); DCC's own trajectory is not shipped",
    ),
    "kitti-07": StandIn(
        "MulRan KAIST", "a shorter loop closed at its end, seen by an OS1-64, as KAIST's campus roads are"
    ),
    "city-tour": StandIn(
        "Apollo SanJose / Sunnyvale",
        "a downtown street grid with revisits in both directions, "
        "HDL-64 (Apollo's sensor); in Table II driven ten times (21.9 km) as Sunnyvale's repeated loops",
    ),
    "reverse-revisit": StandIn(
        "Apollo ColumbiaPark",
        "a road driven out and back in the other lane, HDL-64: the opposite-direction revisits of a park loop",
    ),
    "campus-walk": StandIn(
        "Newer College Park", "a handheld walk at ~0.1 m a frame round two quads, OS1-64 (Newer College's sensor)"
    ),
}
NOT_REPRODUCED = (
    "Real sensor data: every column is simulated (docs/simulator.md says how close the simulator is to KITTI); "
    "MulRan, Apollo-SouthBay and Newer College are stand-ins chosen by trajectory shape and sensor, not those "
    "recordings.",
    "OverlapTransformer: its trained weights are not shipped, so every run uses Scan Context (the paper's SC rows).",
    "Sunnyvale's 100 km: the stand-in drive is 21.9 km (the ablations and distance bounds use its first 6.6 km); "
    "the memory of all samples at 100 km is extrapolated from its measured growth, not measured.",
    "The paper's machine (i9, 128 GB) and absolute times: times here are this machine's, under its load.",
)


def dataset_name(spec: str) -> str:
    """The trajectory name of a sim:/live: spec (`live:city-tour,laps=3` -> `city-tour`)."""
    return spec.split(":", 1)[-1].split(",", 1)[0]


def column_of(spec: str) -> str:
    """The paper column a dataset spec stands in for (its own name when it plays none)."""
    name = dataset_name(spec)
    return STAND_INS[name].column if name in STAND_INS else name


def parse_presets(text: str | None) -> list[str]:
    """The presets to run from "paper-table1,paper-bounds" (None: all of PRESETS, in that order)."""
    if text is None:
        return list(PRESETS)
    names = [item.strip() for item in text.split(",") if item.strip()]
    unknown = [n for n in names if n not in PRESETS]
    if not names or unknown:
        raise InputError(
            f"--presets {text!r}: unknown preset(s) {', '.join(unknown) or '(none given)'}; "
            f"choose from {', '.join(PRESETS)}"
        )
    return [p for p in PRESETS if p in names]


def _prefix(spec: str, frames: int) -> str:
    """The spec cut to its first `frames` frames (the simulator's `end=`), a live: drive of more than QUICK_LAPS
    passes over them to QUICK_LAPS (still forth, back and forth: revisits)."""
    items = [
        f"laps={QUICK_LAPS}" if item.startswith("laps=") and item[5:].isdigit() and int(item[5:]) > QUICK_LAPS else item
        for item in spec.split(",")
    ]
    return ",".join([*items, f"end={frames}"])


def _family_ends(samplers: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """`samplers` (GridSpec.samplers dumped) less the inner members of each family: samplers of one kind that differ
    only in the values of the same parameters (Table II's constants 0.1-3 m, a sweep written out one label at a
    time) keep their first and last, as a sweep keeps its two ends; every other sampler stays."""
    families: dict[tuple, list[int]] = {}
    for i, spec in enumerate(samplers):
        if spec["params"] and not spec["sweep"]:
            families.setdefault((spec["sampler"], tuple(sorted(spec["params"]))), []).append(i)
    inner = {i for members in families.values() for i in members[1:-1]}
    return [spec for i, spec in enumerate(samplers) if i not in inner]


def variant(grid: GridSpec, quick: bool, seeds: Sequence[int] | None) -> GridSpec:
    """`grid` with `seeds` (None: the grid's own) and, with `quick`, cut down: the first QUICK_DATASETS datasets
    on prefixes of QUICK_FRAMES frames (a live: drive of at most QUICK_LAPS passes), one seed, each grid parameter
    at its first value (Table I: oracle), each sweep and each family of samplers (_family_ends) at its two ends.
    The name says it is a variant."""
    data = grid.model_dump()
    if seeds is not None:
        data["seeds"] = list(seeds)
    if quick:
        data["name"] = f"{grid.name}-quick"
        data["seeds"] = data["seeds"][:1]
        data["datasets"] = [
            _prefix(d, QUICK_FRAMES[grid.pipeline]) for d in grid.datasets[: QUICK_DATASETS[grid.pipeline]]
        ]
        data["parameters"] = {k: values[:1] for k, values in grid.parameters.items()}
        data["base"].pop("max_frames", None)  # a cut longer than the prefix: cells the same as the other grids' again
        data["samplers"] = _family_ends(data["samplers"])
        for spec in data["samplers"]:
            spec["sweep"] = {k: sorted({v[0], v[-1]}) for k, v in spec["sweep"].items()}
    return GridSpec(**data)


def paper_grids(presets: Sequence[str], quick: bool, seeds: Sequence[int] | None) -> dict[str, GridSpec]:
    """The grids to run by preset name, each validated and expanded (bad input is found before any cell runs)."""
    from msa_slam.experiments.grid import parse_grid

    out = {}
    for name in presets:
        grid = variant(load_grid(name), quick, seeds)
        out[name] = parse_grid(grid.model_dump(), f"preset {name}")
    return out
