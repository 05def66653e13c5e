"""`msa-slam demo`: the README's main job, all samplers on the embedded simulated KITTI-06."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from msa_slam.cli.options import CACHE_HELP, OVERWRITE_HELP, out_help, reporting_failed_methods


def demo_command(
    out: Optional[Path] = typer.Option(None, help=out_help("demo")),
    overwrite: bool = typer.Option(False, "--overwrite", help=OVERWRITE_HELP),
    cache_dir: Optional[Path] = typer.Option(None, help=CACHE_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bars"),
) -> None:
    """The main job: compare all samplers on the embedded simulated KITTI-06 sequence at 10 Hz (simulated and
    processed with KISS-ICP on first use, then cached); prints the path of its report.md and what it found."""
    from msa_slam.demo import run_demo
    from msa_slam.reporting.findings import findings

    with reporting_failed_methods():
        report = run_demo(out, cache_dir=cache_dir, quiet=quiet, overwrite=overwrite)
        typer.echo(f"report: {report}")
        typer.echo("\n".join(findings(report.parent)))
