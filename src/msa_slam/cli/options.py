"""Help texts and small helpers the commands share (kept here so the library holds no CLI wording)."""

from __future__ import annotations

import contextlib
from typing import Iterator

import typer

SAMPLER_NAMES = ("all", "constant", "entropy", "spaciousness", "msa")  # tests check: == the registry's names
SAMPLER_HELP = f"{', '.join(SAMPLER_NAMES)} (default msa)"
DESCRIPTOR_HELP = "sc (default), ot, precomputed"
MODE_HELP = "oracle (default, the paper) or realistic"
DATASET_HELP = "sequence folder (KITTI layout, scan folder) or sim:NAME (sim:demo, sim:test, sim:kitti-05,...)"
OVERWRITE_HELP = "replace a previous msa-slam result in --out (never anything msa-slam did not write)"
CACHE_HELP = "cache root (default $MSA_SLAM_CACHE or ~/.cache/msa-slam)"
PARAM_HELP = ("override as key=value (repeatable): a config key (similarity_threshold=0.7), a section field "
              "(verifier.max_residual=0.2, graph.robust=cauchy), a stage parameter (sampler.lambda_u=5, "
              "odometry.max_range=80) or a bare sampler parameter")


def out_help(command: str) -> str:
    """--out help text: what the default is and what is refused."""
    return (f"result folder (default: a new ./msa_slam_results/{command}/<date_time>, linked as latest); an existing "
            "folder must be empty or a previous result (with --overwrite)")


@contextlib.contextmanager
def reporting_failed_methods() -> Iterator[None]:
    """A comparison with failed methods: print its report path and one line per failure, exit 1."""
    from msa_slam.pipeline.compare import MethodsFailed

    try:
        yield
    except MethodsFailed as exc:
        typer.echo(str(exc.report))
        for name, error in exc.failed.items():
            typer.echo(f"failed: {name}: {error}", err=True)
        raise typer.Exit(1) from None
