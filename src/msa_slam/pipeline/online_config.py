"""Configuration of the online pipeline: the batch config (same loop, verifier and graph knobs) plus what
only a frame-by-frame run needs (where keyframe clouds live, iSAM2 iterations, sensor rate, noise seed).

Unknown keys are an error listing the valid ones, as for the batch config.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal, Mapping

from pydantic import Field

from msa_slam.pipeline.config import RunConfig, apply_params


class OnlineConfig(RunConfig):
    """One online run (the paper's section V-B protocol).

    `dataset` also accepts `live:NAME[,field=value...,laps=K]`: scans simulated in memory as the run
    needs them (no files), K passes over the trajectory driven forth and back (msa_slam.sim.live).
    `odometry` also accepts "gt-noise": ground-truth motions with random noise (odometry_params
    translation_noise, rotation_noise_deg; seeded by `seed`), for long runs where KISS-ICP would dominate.
    `cloud_store="disk"` keeps downsampled keyframe clouds as .npy files (memory-mapped when read) instead of
    in RAM, in a private folder under `store_dir` (default: the system temporary folder) that is removed when
    the run ends; pick a `store_dir` on a real disk when the temporary folder is in RAM (tmpfs).
    `sensor_rate_hz` is the data's frame rate for the real-time factor only while the frames' timestamps span
    no time (fewer than two frames) or the frames have none (a folder without times.txt or TUM poses);
    otherwise the timestamps give it.
    KISS-ICP runs on every core for a `live:` source and on one thread for recorded data (bit-reproducible);
    `odometry_params: {num_threads: N}` wins (pipeline.online.with_odometry_threads).
    """

    SECTION: ClassVar[str] = "online config"

    cloud_store: Literal["memory", "disk"] = "memory"
    store_dir: str | None = None
    update_iterations: int = Field(2, ge=0)
    sensor_rate_hz: float = Field(10.0, gt=0)
    max_frames: int | None = Field(None, ge=3)
    seed: int = 0


NO_TIMESTAMPS = "sensor_rate_hz (the frames have no timestamps)"  # frame_rate_from without them
NOT_REPRODUCIBLE = "not bit-reproducible (multi-threaded odometry)"  # a run whose KISS-ICP used several threads


def make_online_config(data: Mapping[str, Any] | None = None, **overrides: Any) -> OnlineConfig:
    """A validated OnlineConfig from a mapping plus keyword overrides; problems become one InputError."""
    return OnlineConfig(**{**(dict(data) if data else {}), **overrides})


def apply_online_params(data: Mapping[str, Any], params: list[str]) -> OnlineConfig:
    """`key=value` overrides (YAML values) on an online config mapping: apply_params on its OnlineConfig."""
    return apply_params(make_online_config(data), params)
