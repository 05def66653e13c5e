"""`key=value` command-line overrides, values read as YAML scalars (3 -> int, 0.5 -> float, true -> bool)."""

from __future__ import annotations

from typing import Any

import yaml

from msa_slam.errors import InputError


def parse_key_value(item: str) -> tuple[str, Any]:
    """Split one `--param key=value`; a value YAML cannot read is kept as the raw string."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise InputError(f"--param {item!r}: expected key=value")
    try:
        return key, yaml.safe_load(raw)
    except yaml.YAMLError:
        return key, raw


def parse_params(items: list[str]) -> dict[str, Any]:
    """`key=value` pairs into a mapping; a key given twice is an error rather than a silent last-one-wins."""
    params: dict[str, Any] = {}
    for item in items:
        key, value = parse_key_value(item)
        if key in params:
            raise InputError(f"--param {key} given twice ({params[key]!r} and {value!r}); give it once")
        params[key] = value
    return params
