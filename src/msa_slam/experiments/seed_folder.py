"""The seeds/ folder of a `compare --seeds` result, which lets an interrupted run resume.

    seeds/seed-<n>/           one seed's whole comparison, moved into place only once complete
    seeds/seed-<n>/seed.json  the settings it was run with (dataset without the seed, each method's resolved
                              config), msa-slam's version, the identity of its data and code
                              (msa_slam.experiments.identity) and the methods that failed

A rerun of the same command reuses every finished seed whose record matches (hours of CPU on a whole KITTI
sequence) and runs the others; a finished seed run with other settings is refused before any work, naming the
setting, since mixing it into the spread would compare different experiments. A finished seed whose data or
code changed since it ran (or that records no identity: an older msa-slam ran it) is removed and rerun: its
results would no longer be those of this command. msa-slam's version is no setting: it is part of the code.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import msa_slam
from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import JSONValue
from msa_slam.evaluation.metrics_json import from_json
from msa_slam.evaluation.run_metrics import RunMetrics
from msa_slam.experiments.identity import changed_identity, run_identities
from msa_slam.io.marker import foreign_in_units
from msa_slam.io.outputs import MARKER, OutputError
from msa_slam.io.staging import clean_stale
from msa_slam.io.tables import write_json
from msa_slam.pipeline.config import RunConfig

SEEDS = "seeds"
RECORD = "seed.json"
COMPARISON = "comparison.json"  # a seed's per-method metrics (msa_slam.experiments.compare)
# Where the cache lives changes nothing that is computed, so it is not a setting a seed must match.
NOT_SETTINGS = ("cache_dir",)
IDENTITY = "identity"  # the key of seed.json that records the identity of the seed's data and code
# Keys of seed.json that a rerun does not compare as settings: the version is part of the code identity.
NOT_COMPARED = ("failed", IDENTITY, "version")
_SEED_NAME = re.compile(r"seed-(\d+)")
_LEFTOVER = re.compile(r"\.(seed-\d+)\.(partial|old)-")


def seed_dir(out: Path, seed: int) -> Path:
    return Path(out) / SEEDS / f"seed-{seed}"


@dataclass(frozen=True)
class SeedRecord:
    """seed.json: the settings a seed ran with (`dataset` without the seed, each method's resolved config by label,
    whether its methods ran the threshold sweep), msa-slam's version and, once it ran, the identity of its data
    and code and the methods that failed (label -> error)."""

    version: str
    dataset: str
    methods: Mapping[str, Mapping[str, JSONValue]]
    threshold_sweep: bool
    identity: Mapping[str, JSONValue] | None = None
    failed: Mapping[str, str] = field(default_factory=dict)

    def settings(self) -> dict[str, JSONValue]:
        """What a finished seed must match to be reused (the version is no setting: it is part of the code)."""
        return {"dataset": self.dataset, "methods": dict(self.methods), "threshold_sweep": self.threshold_sweep}

    def to_json(self) -> dict[str, JSONValue]:
        identity = None if self.identity is None else dict(self.identity)
        return {"version": self.version, **self.settings(), IDENTITY: identity, "failed": dict(self.failed)}

    @classmethod
    def from_json(cls, data: Any, where: str) -> SeedRecord:
        """The record of a seed.json; InputError naming `where` for a missing setting or a wrong type (a record
        without the methods that failed lists none; one without an identity is rerun: changed_identity)."""
        if not isinstance(data, dict):
            raise InputError(f"{where}: expected a JSON object")
        data = {"version": "", "failed": {}, **data}
        for key, kind in {
            "version": str,
            "dataset": str,
            "methods": dict,
            "threshold_sweep": bool,
            "failed": dict,
        }.items():
            if not isinstance(data.get(key), kind):
                raise InputError(f"{where}: {key}: expected {kind.__name__}, got {data.get(key)!r}")
        identity = data.get(IDENTITY)
        return cls(
            data["version"],
            data["dataset"],
            data["methods"],
            data["threshold_sweep"],
            identity if isinstance(identity, dict) else None,
            data["failed"],
        )


def seed_record(dataset: str, configs: Sequence[RunConfig], sweep: bool = True) -> SeedRecord:
    """What a finished seed must have been run with to be reused: `dataset` is the one without the seed,
    `sweep` whether its methods ran the threshold sweep."""
    methods = {cfg.name: {k: v for k, v in cfg.dump().items() if k not in NOT_SETTINGS} for cfg in configs}
    return SeedRecord(msa_slam.__version__, dataset, json.loads(json.dumps(methods)), sweep)


def seed_identities(plans: Mapping[int, Sequence[RunConfig]]) -> dict[int, dict[str, str | None]]:
    """{"data": ..., "code": ...} of each seed (`plans`: seed -> its methods' configs): a sim: seed's data is
    its simulation key, which holds the world seed (msa_slam.experiments.identity)."""
    return run_identities({seed: [cfg.dump() for cfg in configs] for seed, configs in plans.items()})


def write_record(
    folder: Path, record: SeedRecord, identity: Mapping[str, str | None], failed: Mapping[str, str]
) -> None:
    write_json(Path(folder) / RECORD, replace(record, identity=identity, failed=failed).to_json())


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def finished_metrics(folder: Path) -> list[RunMetrics] | None:
    """The per-method reports of a finished seed; None when missing or damaged (the seed is then run again)."""
    path = Path(folder) / COMPARISON
    methods = _read_json(path)
    if not isinstance(methods, list):
        return None
    try:
        return [from_json(m, f"{path} (method {i + 1})") for i, m in enumerate(methods)]
    except InputError:
        return None


def check_seed_folder(out: Path) -> None:
    """Without --overwrite, `out` must hold a `compare --seeds` result (its seeds/ folder) or nothing yet."""
    if out.is_dir() and not (out / SEEDS).is_dir() and any(p.name != MARKER for p in out.iterdir()):
        raise OutputError(
            f"--out {out}: holds a comparison run without --seeds; pass --overwrite to replace it "
            "or choose another --out"
        )


def clean_leftovers(out: Path) -> list[Path]:
    """Remove the staging folders of seeds a kill interrupted (call with the result folder's lock held)."""
    seeds = Path(out) / SEEDS
    names = {m.group(1) for p in seeds.iterdir() if (m := _LEFTOVER.match(p.name))} if seeds.is_dir() else set()
    return [path for name in sorted(names) for path in clean_stale(seeds / name)]


@dataclass
class Resume:
    """What a rerun does with the seeds finished earlier: reuse them, or run them again (seed -> the line saying
    why: its data or code changed since)."""

    reusable: list[int] = field(default_factory=list)
    rerun: dict[int, str] = field(default_factory=dict)


def resume_seeds(
    out: Path, records: Mapping[int, SeedRecord], identities: Mapping[int, Mapping[str, str | None]]
) -> Resume:
    """Which seeds of `records` (seed -> expected record) finished earlier in `out` are reused (same settings,
    data and code, no failed method) and which are rerun (same settings, other data or code: `identities`, seed
    -> current identity). Raises OutputError, before any work, for a finished seed run with other settings or
    without a record."""
    resume = Resume()
    for seed, expected in records.items():
        folder = seed_dir(out, seed)
        if not folder.is_dir():
            continue
        unreadable = OutputError(
            f"--out {out}: seed {seed} has no readable record of the settings it was run with "
            f"({SEEDS}/seed-{seed}/{RECORD}); pass --overwrite to replace the folder"
        )
        data = _read_json(folder / RECORD)
        if not isinstance(data, dict):
            raise unreadable
        difference = first_difference({k: v for k, v in data.items() if k not in NOT_COMPARED}, expected.settings())
        if difference is not None:
            key, there, now = difference
            raise OutputError(
                f"--out {out}: seed {seed} was run with other settings ({key}: {there} there, {now} "
                "now); rerun with the same settings to resume, or pass --overwrite to replace the "
                "folder"
            )
        try:
            record = SeedRecord.from_json(data, str(folder / RECORD))
        except InputError:
            raise unreadable from None
        reason = changed_identity(record.identity, identities[seed])
        if reason is not None:
            resume.rerun[seed] = f"seed {seed}: {reason}; rerun"
        elif not record.failed and finished_metrics(folder) is not None:
            resume.reusable.append(seed)
    return resume


def remove_seeds(out: Path, seeds: Mapping[int, str]) -> None:
    """Remove the folders of `seeds` (seed -> why it is rerun) before they are rerun, so that none is reported
    beside results of the current data and code. Each is moved aside first (clean_leftovers removes what a kill
    leaves), so a kill never leaves half a seed. Only msa-slam's: a folder holding files it did not write, or
    that were edited since, is refused (OutputError, before any of them is touched)."""
    for seed, kept in not_msa_slams(out, seeds).items():
        if kept:
            raise OutputError(
                f"--out {out}: {seeds[seed].removesuffix('; rerun')}, but its folder holds files "
                f"msa-slam did not write or that were edited since ({', '.join(kept[:3])}"
                f"{', ...' if len(kept) > 3 else ''}); move them out to rerun it"
            )
    for seed in seeds:
        folder = seed_dir(out, seed)
        aside = folder.parent / f".{folder.name}.old-{os.getpid()}-{time.monotonic_ns()}"
        os.replace(folder, aside)
        shutil.rmtree(aside, ignore_errors=True)


def not_msa_slams(out: Path, seeds: Iterable[int]) -> dict[int, list[str]]:
    """Per seed, the files in its folder (paths relative to `out`) that the result marker does not list as
    msa-slam's or that changed since it wrote them (marker.foreign_in_units)."""
    found = foreign_in_units(out, [f"{SEEDS}/seed-{seed}" for seed in seeds], edited=True)
    return {seed: found[f"{SEEDS}/seed-{seed}"] for seed in seeds}


def left_out_seeds(out: Path, seeds: Sequence[int]) -> list[int]:
    """Finished seeds in `out` that are not among `seeds` (a rerun with fewer seeds): kept, not in the spread."""
    folder = Path(out) / SEEDS
    found = (
        [int(m.group(1)) for p in folder.iterdir() if p.is_dir() and (m := _SEED_NAME.fullmatch(p.name))]
        if folder.is_dir()
        else []
    )
    return sorted(set(found) - set(seeds))


_ABSENT = object()


def first_difference(there: Any, now: Any, key: str = "") -> tuple[str, str, str] | None:
    """The first setting (dotted key) whose value differs between two records, with both values shown."""
    if isinstance(there, dict) and isinstance(now, dict):
        for name in [*there, *(k for k in now if k not in there)]:
            found = first_difference(there.get(name, _ABSENT), now.get(name, _ABSENT), f"{key}.{name}" if key else name)
            if found is not None:
                return found
        return None
    return None if there == now else (key, _show(there), _show(now))


def _show(value: Any, limit: int = 60) -> str:
    if value is _ABSENT:
        return "absent"
    text = json.dumps(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
