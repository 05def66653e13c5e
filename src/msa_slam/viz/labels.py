"""Names as a person reads them in figure titles and reports: cache hashes dropped from sequence names
(`figure-eight_hdl64_32fb48a...` -> `figure-eight (hdl64)`), samplers with the parameters a run gave them,
counts with their noun in the right number ("1 loop", "7 loops")."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

_HASHED = re.compile(r"^(?P<name>.+?)(?:_(?P<sensor>[A-Za-z0-9-]+))?_[0-9a-f]{12,}$")


def display_name(sequence: str) -> str:
    """`sequence` without a trailing content hash; a simulated `<trajectory>_<sensor>_<hash>` reads
    `<trajectory> (<sensor>)`. Names without a hash are returned unchanged."""
    match = _HASHED.match(sequence)
    if match is None:
        return sequence
    sensor = match["sensor"]
    return f"{match['name']} ({sensor})" if sensor else match["name"]


def sampler_label(sampler: str, params: Mapping[str, Any]) -> str:
    """A sampler with the parameters the run gave it, e.g. `constant (distance=2)`; the name alone with none."""
    given = ", ".join(f"{key}={value}" for key, value in sorted(params.items()))
    return f"{sampler} ({given})" if given else sampler


def counted(n: int, noun: str) -> str:
    """`n` and `noun`, the noun in the plural unless `n` is 1 ("1 loop", "0 loops", "7 loops"): a title reading
    "1 loops" looks like a typo and makes a reader doubt the number."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def absent_note(absent: Mapping[str, str], lead: str = "") -> str:
    """`lead` + "not shown: <name> (<why>), ..." for the methods a figure leaves out; "" when none is: a method
    missing from a figure without a word reads as one never run."""
    if not absent:
        return ""
    return lead + "not shown: " + ", ".join(f"{name} ({why})" for name, why in absent.items())
