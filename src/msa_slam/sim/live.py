"""A `live:` source (`live:NAME[,key=value...,laps=K]`, parsed by msa_slam.sources): the simulator's scans made in memory when a run asks for them, so
long runs need no disk. With K laps the trajectory is driven forth, back, forth... (each pass reversed, so
the path stays continuous and every pass revisits the whole route; each pass has its own sensor noise).
`live:city-tour,laps=10` is a 22 km tour."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from msa_slam.datasets import Frame
from msa_slam.datasets.vertical_angle import raise_elevation
from msa_slam.types import FrameSource

if TYPE_CHECKING:
    from msa_slam.sim.config import SimConfig


def live_source(config: SimConfig, laps: int = 1, name: str | None = None) -> FrameSource:
    """The frame source of simulation `config` driven `laps` times (msa_slam.sources parses a `live:` spec into
    them), named after `name` (default: its trajectory); its scans are simulated as the frames are read."""
    from msa_slam.sim import prepare

    sim = prepare(config)
    name = config.label if name is None else name
    order = [np.arange(len(sim)) if lap % 2 == 0 else np.arange(len(sim))[::-1] for lap in range(laps)]
    lap_of = np.repeat(np.arange(laps), len(sim))
    index = np.concatenate(order)
    gt = sim.poses[index]
    dt = 1.0 / 10.0 if len(sim.times) < 2 else float(np.median(np.diff(sim.times)))

    def frames() -> Iterator[Frame]:
        for i, (k, lap) in enumerate(zip(index, lap_of)):
            rng = np.random.default_rng([sim.config.seed, int(lap), int(sim.frames[k])])
            points = sim.lidar.scan(sim.poses[k], rng, float(sim.trajectory.times[sim.frames[k]]))[:, :3]
            if sim.realism.sensor.elevation_bias_deg:  # corrected as the KITTI-layout reader corrects sim.json's
                points = raise_elevation(points)
            yield Frame(i, i * dt, points, gt[i])

    label = f"live-{name}" + (f"-x{laps}" if laps > 1 else "")
    # the simulated frames carry no per-point times; they are streamed like a sensor's (KISS-ICP on every core)
    identity = f"simulation {config.key()}, laps {laps}"  # every frame follows from these (seeds included)
    return FrameSource(label, gt, frames, point_times=False, live=True, identity=identity)
