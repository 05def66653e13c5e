"""Checked reading of a metrics.json document: every key a report needs must be there with the right type, and a
missing or wrong one is one InputError naming the file and the key (its dotted path), before anything is built.

The one place that turns JSON nulls into `Unavailable` values: with the reason metrics.json's `unavailable`
gives under the first of the metric's reason keys present (the keys docs/metrics.md lists).
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping
from typing import Any

from msa_slam.errors import InputError
from msa_slam.evaluation.metrics import Unavailable, Value

NO_REASON = (
    "this cell's metrics.json holds neither a value nor a reason (cells written by older msa-slam versions "
    "lack some metrics)"
)
_ACCEPTED = {int: numbers.Integral, float: numbers.Real}  # numpy's too (a fresh run's figures); bool apart
_TYPES = {
    int: "an integer",
    float: "a number",
    str: "a string",
    bool: "true or false",
    dict: "an object",
    list: "a list",
}


class MetricsDocument:
    """A metrics.json object (or one of its objects, at `path`) read key by key with its types checked."""

    def __init__(self, data: Any, source: str, path: str = "", reasons: Mapping[str, str] | None = None) -> None:
        self.source, self.path = source, path
        if not isinstance(data, dict):
            raise self.error(path or "(top level)", f"must be an object, not {_shown(data)}")
        self.data = data
        self.reasons: Mapping[str, str] = reasons if reasons is not None else {}

    def error(self, key: str, problem: str) -> InputError:
        return InputError(
            f"{self.source}: metrics key {key!r} {problem} (written by another msa-slam version, or edited?)"
        )

    def _where(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def has(self, key: str) -> bool:
        """Whether the optional `key` is recorded (keys only some runs write: docs/metrics.md)."""
        return key in self.data

    def raw(self, key: str) -> Any:
        if key not in self.data:
            raise self.error(self._where(key), "is missing")
        return self.data[key]

    def typed(self, key: str, kind: type | tuple[type, ...], nullable: bool = False) -> Any:
        """The value of `key`, checked to be of `kind` (int accepted for float; bool never for a number)."""
        value = self.raw(key)
        if value is None and nullable:
            return None
        kinds = kind if isinstance(kind, tuple) else (kind,)
        accepted = tuple(_ACCEPTED.get(k, k) for k in kinds)
        if not isinstance(value, accepted) or (isinstance(value, bool) and bool not in kinds):
            wanted = " or ".join(_TYPES[k] for k in kinds) + (" or null" if nullable else "")
            raise self.error(self._where(key), f"must be {wanted}, not {_shown(value)}")
        return value

    def value(self, key: str, *reason_keys: str, kind: type = float, default: str = NO_REASON) -> Value:
        """A number, or Unavailable with the first reason recorded under `reason_keys` when it is null."""
        number = self.typed(key, kind, nullable=True)
        if number is not None:
            return number
        return self.unavailable(*reason_keys, default=default)

    def unavailable(self, *reason_keys: str, default: str = NO_REASON) -> Unavailable:
        """Why a null value is missing: the first reason recorded under `reason_keys` (a text's or a flag's too)."""
        return Unavailable(next((self.reasons[k] for k in reason_keys if k in self.reasons), default))

    def sub(self, key: str) -> MetricsDocument:
        return MetricsDocument(self.raw(key), self.source, self._where(key), self.reasons)

    def mapping(self, key: str, kind: type | tuple[type, ...] | None = None, nullable: bool = False) -> dict:
        """An object whose values are all of `kind` (None: any JSON value)."""
        table = self.sub(key).data
        if kind is not None:
            for name in table:
                self.sub(key).typed(name, kind, nullable)
        return table


def _shown(value: Any) -> str:
    text = repr(value)
    return f"{text[:40]}... ({type(value).__name__})" if len(text) > 40 else f"{text} ({type(value).__name__})"
