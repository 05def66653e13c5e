"""A `live:` source (`live:NAME[,key=value...,laps=K]`, parsed by msa_slam.sources): the simulator's scans made in memory when a run asks for them, so
long runs need no disk. With K laps the trajectory is driven forth, back, forth... (each pass reversed, so
the path stays continuous and every pass revisits the whole route; each pass has its own sensor noise).
`live:city-tour,laps=10` is a 22 km tour."""

from __future__ import annotations

from collections.abc import Iterator
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from msa_slam.datasets import Frame
from msa_slam.datasets.vertical_angle import raise_elevation
from msa_slam.types import FrameSource

if TYPE_CHECKING:
    from msa_slam.sim.config import SimConfig
    from msa_slam.sim.simulation import Simulation


def live_source(config: SimConfig, laps: int = 1, name: str | None = None) -> FrameSource:
    """The frame source of simulation `config` driven `laps` times (msa_slam.sources parses a `live:` spec into
    them), named after `name` (default: its trajectory); its scans are simulated as the frames are read, here
    (`frames`) or in another process (`producer`: live_frames, the same frames)."""
    from msa_slam.sim import prepare

    sim = prepare(config)
    name = config.label if name is None else name
    index, _ = _lap_order(len(sim), laps)
    label = f"live-{name}" + (f"-x{laps}" if laps > 1 else "")
    # the simulated frames carry no per-point times; they are streamed like a sensor's (KISS-ICP on every core)
    identity = f"simulation {config.key()}, laps {laps}"  # every frame follows from these (seeds included)
    return FrameSource(
        label,
        sim.poses[index],
        partial(_simulated, sim, laps),
        point_times=False,
        live=True,
        identity=identity,
        producer=partial(live_frames, config, laps),
    )


def live_frames(config: SimConfig, laps: int) -> Iterator[Frame]:
    """The frames of live_source(config, laps), simulated one by one in the calling process, which builds the
    simulation itself (a process spawned to make them, as a sensor's driver delivers scans: pipeline.live)."""
    from msa_slam.sim import prepare

    return _simulated(prepare(config), laps)


def _lap_order(frames: int, laps: int) -> tuple[np.ndarray, np.ndarray]:
    """The simulation's frame of each live frame (each pass reversed after the first), and the lap it is in."""
    order = [np.arange(frames) if lap % 2 == 0 else np.arange(frames)[::-1] for lap in range(laps)]
    return np.concatenate(order), np.repeat(np.arange(laps), frames)


def _simulated(sim: Simulation, laps: int) -> Iterator[Frame]:
    """The live frames of `sim` driven `laps` times, each scan cast as it is asked for."""
    index, lap_of = _lap_order(len(sim), laps)
    gt = sim.poses[index]
    dt = 1.0 / 10.0 if len(sim.times) < 2 else float(np.median(np.diff(sim.times)))
    for i, (k, lap) in enumerate(zip(index, lap_of)):
        rng = np.random.default_rng([sim.config.seed, int(lap), int(sim.frames[k])])
        points = sim.lidar.scan(sim.poses[k], rng, float(sim.trajectory.times[sim.frames[k]]))[:, :3]
        if sim.realism.sensor.elevation_bias_deg:  # corrected as the KITTI-layout reader corrects sim.json's
            points = raise_elevation(points)
        yield Frame(i, i * dt, points, gt[i])
