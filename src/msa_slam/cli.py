"""The `msa-slam` command line: thin entry points over the library (each command lives with its stage)."""

from __future__ import annotations

import sys

import typer

from msa_slam.errors import InputError
from msa_slam.sampling.cli import sample_command
from msa_slam.pipeline.online_cli import online_command
from msa_slam.experiments.cli import experiment_command, report_command
from msa_slam.pipeline.cli import compare_command, demo_command, run_command
from msa_slam.sim.cli import simulate_command

app = typer.Typer(
    name="msa-slam",
    help="Informed keyframe sampling (Minimal Subset Approach) for LiDAR SLAM, with a measured back-end.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _main() -> None:
    """msa-slam command line."""


# Command registrations (one line per command; the functions live with their stage).
app.command("simulate")(simulate_command)
app.command("run")(run_command)
app.command("compare")(compare_command)
app.command("demo")(demo_command)
app.command("sample")(sample_command)
app.command("online")(online_command)
app.command("experiment")(experiment_command)
app.command("report")(report_command)
# -- end of command registrations --


def main() -> None:
    """Entry point: usage errors as click prints them; InputError as one clear line with exit code 2."""
    try:
        app()
    except InputError as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)
