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


def source_options(base: dict[str, Any], loader: Optional[str], **given: Any) -> dict[str, Any]:
    """--loader and the source options given (--topic, --gt, --sequence, --first, --jump, -n) as config keys:
    `dataset_kind` and the file's `source` section updated (None values: not given)."""
    given = {k: (str(v) if isinstance(v, Path) else v) for k, v in given.items() if v is not None}
    source = {**(base.get("source") or {}), **given} if given else None
    return {"dataset_kind": loader, "source": source}
