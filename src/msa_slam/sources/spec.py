"""The dataset argument every command takes, parsed in one place: `parse_spec(text) -> SourceSpec`.

Spellings:
- a recording: a sequence folder (KITTI layout, a folder of .bin/.pcd/.ply scans, MulRan, HeLiPR, ...) or a
  ROS1/ROS2 bag; its loader is chosen from the layout when it is opened (msa_slam.datasets.LOADERS);
- `sim:NAME[,key=value...]`: a simulated sequence, cached on disk. NAME is an embedded default (`sim:demo`,
  `sim:test`), a shipped trajectory (`sim:kitti-05,stride=3`) or a pose file; a spec that starts with a
  key (`sim:trajectory=/data/poses.txt,times=/data/times.txt`) starts from the simulator's defaults;
- `live:NAME[,key=value...,laps=K]`: the same, simulated in memory as a run reads it, K passes forth and back.

The keys are SimConfig's fields (and `laps` for live:); values are read as YAML, except the paths
(trajectory, times, calib), taken verbatim so that a file named 1e3 stays a path. Items are split at commas,
so paths cannot hold one. `{seed}` in an experiment grid's dataset is replaced by each of its seeds (seeded).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import yaml

from msa_slam.errors import InputError

if TYPE_CHECKING:
    from msa_slam.sim import SimConfig

SIM_PREFIX = "sim:"
LIVE_PREFIX = "live:"
SEED = "{seed}"
PATH_FIELDS = ("trajectory", "times", "calib")  # taken verbatim: a file named 1e3 stays a path
LIVE_FIELDS = ("laps",)  # a live: source's keys besides the simulation's
Kind = Literal["recording", "sim", "live"]


@dataclass(frozen=True)
class SourceSpec:
    """A dataset argument, checked: a recording's path exists; a simulated one's keys and values are valid
    (its SimConfig is built, nothing is simulated)."""

    text: str  # as given (after {seed} substitution): errors and results name it so
    kind: Kind
    path: Path | None = None  # recording: the folder or bag
    name: str = ""  # sim/live: the name given first (default, trajectory or pose file); "" when keys only
    fields: tuple[tuple[str, Any], ...] = ()  # sim/live: the key=value items, values as parsed
    laps: int = 1  # live: passes over the trajectory
    config: SimConfig | None = None  # sim/live: the validated simulation

    @property
    def simulated(self) -> bool:
        """True for sim: and live: (no recording options apply)."""
        return self.kind != "recording"

    @property
    def simulation(self) -> SimConfig:
        """The validated simulation of a sim: or live: spec (a recording has none)."""
        if self.config is None:
            raise ValueError(f"dataset {self.text!r}: a recording has no simulation")
        return self.config

    @property
    def keys(self) -> tuple[str, ...]:
        """The keys the spec sets (sim/live)."""
        return tuple(key for key, _ in self.fields)

    @property
    def label(self) -> str:
        """The name given first, else the simulation's (its trajectory)."""
        return self.name or (self.config.label if self.config is not None else self.text)

    def loader(self) -> str:
        """The loader a recording's layout calls for (msa_slam.datasets.LOADERS); a dataset root given with
        --sequence is resolved to its sequence when opened."""
        from msa_slam.datasets import detect_loader

        if self.path is None:
            raise InputError(f"dataset {self.text!r}: a {self.kind}: dataset is simulated, not read by a loader")
        return detect_loader(self.path)


def spec_kind(text: str) -> Kind:
    """What `text` names, by its prefix alone (nothing checked)."""
    return "sim" if text.startswith(SIM_PREFIX) else "live" if text.startswith(LIVE_PREFIX) else "recording"


def seeded(text: str, seed: int) -> str:
    """`text` with an experiment grid's `{seed}` replaced by `seed`."""
    return text.replace(SEED, str(seed))


def parse_spec(text: str, seed: int | None = None) -> SourceSpec:
    """The SourceSpec of dataset argument `text` (with `{seed}` replaced by `seed` when given); one InputError
    naming the spec, the key and the valid keys or values when it is bad."""
    if seed is not None:
        text = seeded(text, seed)
    kind = spec_kind(text)
    if kind != "recording":
        return _simulated(text, kind)
    path = Path(text).expanduser()
    if not path.exists():
        raise InputError(f"dataset {text!r}: not found (give a sequence folder, a bag or sim:NAME)")
    return SourceSpec(text, "recording", path=path)


def _simulated(text: str, kind: Kind) -> SourceSpec:
    from msa_slam.sim import DEFAULT_CONFIGS, TRAJECTORY_NAMES, SimConfig, make_config

    where = f"dataset {text!r}"
    names = ", ".join([*DEFAULT_CONFIGS, *TRAJECTORY_NAMES])
    if SEED in text:
        raise InputError(f"{where}: {SEED} is replaced only in an experiment grid's datasets (by each of its seeds)")
    items = text[len(SIM_PREFIX if kind == "sim" else LIVE_PREFIX) :].split(",")
    name, items = ("", items) if "=" in items[0] else (items[0].strip(), items[1:])
    if not name and not items:  # e.g. sim:$SEQUENCE with the variable unset
        raise InputError(
            f"{where}: names no simulated sequence; give {kind}:NAME (one of {names}) or keys "
            f"({kind}:trajectory=FILE,...)"
        )
    valid = [*SimConfig.model_fields, *(LIVE_FIELDS if kind == "live" else ())]
    fields = _fields(items, valid, where)
    values = dict(fields)
    laps = values.pop("laps", 1)
    if isinstance(laps, bool) or not isinstance(laps, int) or laps < 1:
        raise InputError(f"{where}: laps must be an integer >= 1, got {laps!r}")
    if name in DEFAULT_CONFIGS:
        config = DEFAULT_CONFIGS[name]
        base = config.model_dump()
    elif name in TRAJECTORY_NAMES or "/" in name or "." in name:  # a pose file: no shipped name has / or .
        config, base = None, {"trajectory": name}
    elif not name:
        config, base = None, {}
    else:
        raise InputError(
            f"{where}: unknown simulated sequence {name!r}; choose one of {names}, or give keys only "
            f"({kind}:trajectory=/path/poses.txt,...)"
        )
    if values or config is None:
        config = make_config(where=where, **{**base, **values})
    return SourceSpec(text, kind, name=name, fields=fields, laps=laps, config=config)


def _fields(items: list[str], valid: list[str], where: str) -> tuple[tuple[str, Any], ...]:
    """(key, value) of each `key=value` item, every key one of `valid` and given once."""
    fields: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep:
            raise InputError(f"{where}: expected key=value, got {item!r}; valid keys: {', '.join(valid)}")
        if key not in valid:
            raise InputError(f"{where}: unknown key {key!r}; valid keys: {', '.join(valid)}")
        if key in fields:
            raise InputError(f"{where}: key {key!r} is given twice")
        fields[key] = raw.strip() if key in PATH_FIELDS else _value(raw)
    return tuple(fields.items())


def _value(raw: str) -> Any:
    """A value as YAML reads it (3 -> int, 0.5 -> float, true -> bool); text YAML cannot read stays text."""
    try:
        return yaml.safe_load(raw)
    except yaml.YAMLError:
        return raw.strip()
