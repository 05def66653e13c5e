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


def sampler_window(config: Any) -> Optional[int]:
    """The window of the config's sampler (MSA's N; None for a sampler without one)."""
    from msa_slam.sampling import make_sampler

    return getattr(make_sampler(config.sampler, **config.sampler_params), "window_size", None)


def check_window(config: Any, n_frames: int, fix: str) -> None:
    """Before the front end: a sampler window longer than the `n_frames` read never fills, so the run could end,
    after odometry and descriptors, with too few keyframes for the evaluation. Without the end-of-stream flush
    only frame 0 is ever a keyframe: an error with `fix` (formatted with `frames` and `window`); with it, the
    sampler's own warning now rather than after the front end (a warning, as the flush may still pick enough)."""
    from msa_slam.sampling import make_sampler
    from msa_slam.slam.backend import MIN_KEYFRAMES

    sampler = make_sampler(config.sampler, **config.sampler_params)
    window = getattr(sampler, "window_size", None)
    if window is None or n_frames >= window:
        return
    if not config.flush:
        raise InputError(f"sampler {config.name!r}: window={window} is longer than the {n_frames} frames read, so it "
                         f"never fills and only frame 0 becomes a keyframe (flush is off); the evaluation needs at "
                         f"least {MIN_KEYFRAMES}: " + fix.format(frames=n_frames, window=window))
    sampler.expect_frames(n_frames)


def check_windows(configs: list, quiet: bool, fix: str) -> None:
    """check_window for each of a batch command's configs (one dataset), counting the frames read (by opening
    the dataset, as the front end will again) only when a sampler has a window."""
    from msa_slam.pipeline.source import open_sequence

    if all(sampler_window(c) is None for c in configs):
        return
    first = configs[0]
    n_frames = len(open_sequence(first.dataset, first.dataset_kind, first.cache_dir, not quiet, first.source,
                                 first.mode))
    for config in configs:
        check_window(config, n_frames, fix)
