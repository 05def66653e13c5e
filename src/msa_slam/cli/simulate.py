"""`msa-slam simulate`: write (or reuse) a simulated sequence in the KITTI odometry layout."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from msa_slam.cli.options import CACHE_HELP


def simulate_command(
    trajectory: str = typer.Option(
        "kitti-05",
        help="kitti-00/05/06/07/09, figure-eight, city-tour, reverse-revisit, "
        "campus-walk, "
        "or a pose file: KITTI (12 numbers a line) or TUM (t x y z qx qy qz qw), "
        "LiDAR frame (x forward, z up) unless --calib",
    ),
    times: Optional[Path] = typer.Option(None, help="times of a KITTI-format file, one a line (default 10 Hz)"),
    calib: Optional[Path] = typer.Option(
        None, help="KITTI calib.txt: its Tr line converts the file's cam0 poses to the LiDAR frame (inv(Tr) P Tr)"
    ),
    trajectory_format: str = typer.Option("auto", help="format of a trajectory file: auto, kitti or tum"),
    sensor: str = typer.Option("hdl64", help="hdl64, os1-64 or os1-128"),
    out: Optional[Path] = typer.Option(None, help="output directory (default: the cache, keyed by config hash)"),
    start: int = typer.Option(0, help="first trajectory frame"),
    end: Optional[int] = typer.Option(None, help="end frame (exclusive; default: the whole trajectory)"),
    stride: int = typer.Option(1, help="keep every stride-th frame"),
    seed: int = typer.Option(0, help="seed of the world and the sensor noise"),
    azimuth_steps: Optional[int] = typer.Option(None, help="rays per beam per revolution (sensor default)"),
    max_range: Optional[float] = typer.Option(
        None,
        help="maximum range, metres (sensor default); at least the "
        "lowest beam's way down to the ground (4.1 m for hdl64 on a car)",
    ),
    range_noise: float = typer.Option(0.02, help="Gaussian range noise sigma, metres"),
    dropout: float = typer.Option(0.0, help="fraction of returns dropped at random"),
    style: Optional[str] = typer.Option(None, help="world style: city or campus (default from the platform)"),
    realism: str = typer.Option(
        "kitti",
        help="realism preset: kitti (calibrated against KITTI: motion distortion, "
        "sensor imperfections, a changing world), kitti-hard (kitti with several times its "
        "odometry drift) or clean (static world, ideal sensor)",
    ),
    cache_dir: Optional[Path] = typer.Option(None, help=CACHE_HELP),
    workers: Optional[int] = typer.Option(
        None,
        min=0,
        help="processes casting scans (0: this one; default: one "
        "per CPU, at most 4, for 300 scans or more); the files do not depend on it",
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Simulate a LiDAR sequence (velodyne/*.bin, poses.txt, times.txt, calib.txt) and print its folder."""
    from msa_slam.sim import make_config, simulate_sequence

    config = make_config(
        trajectory=trajectory,
        sensor=sensor,
        start=start,
        end=end,
        stride=stride,
        seed=seed,
        azimuth_steps=azimuth_steps,
        max_range=max_range,
        range_noise=range_noise,
        dropout=dropout,
        style=style,
        realism=realism,
        trajectory_format=trajectory_format,
        times=None if times is None else str(times),
        calib=None if calib is None else str(calib),
    )
    path = simulate_sequence(config, out=out, cache_dir=cache_dir, progress=not quiet, workers=workers)
    typer.echo(str(path))
