"""Command-line options over a config file: the one merge rule `run`, `compare` and `online` share."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

from msa_slam.errors import InputError


def merge_options(base: dict[str, Any], given: dict[str, Any], datasets: str) -> dict[str, Any]:
    """`given` options (None = not given) over a config mapping; a new sampler drops the file's parameters.

    `datasets` names what --dataset accepts, for the error when neither the options nor the file give one.
    """
    data = dict(base)
    sampler = given.get("sampler")
    if sampler is not None and base.get("sampler") not in (None, sampler):
        data["sampler_params"] = {}
    data.update({k: v for k, v in given.items() if v is not None})
    if "dataset" not in data:
        raise InputError(f"--dataset is required ({datasets}), or give --config")
    return data


def cache_option(cache_dir: Optional[Path]) -> Optional[str]:
    """--cache-dir as the config stores it."""
    return None if cache_dir is None else str(cache_dir)
