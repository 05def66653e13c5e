"""`msa-slam sample`: run a registered sampler over a stream given as files."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from msa_slam.cli.options import SAMPLER_NAMES


def sample_command(
    poses: Path = typer.Option(..., "--poses", help="Pose file (KITTI 12 numbers a line, or TUM)."),
    descriptors: Optional[Path] = typer.Option(
        None, "--descriptors", help=".npy array (N, ...) of per-frame descriptors (msa)."
    ),
    clouds: Optional[Path] = typer.Option(
        None, "--clouds", help="Folder of scans or .npy (N, P, 3) (entropy, spaciousness)."
    ),
    sampler: str = typer.Option("msa", "--sampler", help=f"One of: {', '.join(SAMPLER_NAMES)}."),
    param: list[str] = typer.Option([], "--param", "-p", help="Sampler parameter key=value (repeatable)."),
    pose_format: str = typer.Option("auto", "--pose-format", help="auto, kitti or tum."),
    out: Optional[Path] = typer.Option(
        None,
        "--out",
        help="Output folder (default: a new ./msa_slam_results/sample/"
        "<date_time>, linked as latest); an existing folder must be empty or a "
        "previous result (with --overwrite).",
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a previous msa-slam result in --out."),
    flush: bool = typer.Option(False, "--flush", help="Flush the last window at the end (reported apart)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Select keyframes from a pose stream; write keyframes.txt, keyframes.json and keyframes.png."""
    from msa_slam.io.params import parse_params
    from msa_slam.sampling.files import sample_files

    folder, keyframes, frames = sample_files(
        poses, descriptors, clouds, sampler, parse_params(param), pose_format, out, overwrite, flush, quiet
    )
    typer.echo(f"{keyframes} keyframes of {frames} frames -> {folder}/keyframes.txt, keyframes.json, keyframes.png")
