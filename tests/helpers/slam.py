"""The SLAM core of a test's configuration, built as the pipelines build it (its sampler, its loop closer)."""

from __future__ import annotations

from typing import Any

from msa_slam.slam import SlamBackend, build_backend, build_loop_closer, slam_sampler


def config_backend(
    config: Any, descriptor: Any, clouds: Any, graph: Any, n_frames: int, name: str, sampler: Any = None
) -> SlamBackend:
    """build_backend with the config's own gated sampler (or `sampler`) and loop closer."""
    return build_backend(
        config, sampler or slam_sampler(config), build_loop_closer(config, descriptor, clouds), graph, n_frames, name
    )
