"""`msa-slam run`: one sampler through the batch pipeline (the paper's Table I protocol)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from msa_slam.cli.options import (
    CACHE_HELP,
    DATASET_HELP,
    DESCRIPTOR_HELP,
    MODE_HELP,
    OVERWRITE_HELP,
    PARAM_HELP,
    SAMPLER_HELP,
    WINDOW_FIX,
    out_help,
    with_source_options,
)


def batch_config(config_file: Optional[Path], given: dict, params: list[str], source: Optional[dict] = None):
    """The RunConfig of `run` / `compare`: the options over --config, then the --param overrides; `source`:
    --loader and the source options (cli.config.source_options' arguments)."""
    from msa_slam.cli.config import merge_options, source_options
    from msa_slam.pipeline.config import apply_params, make_config, read_config_file

    base = read_config_file(config_file) if config_file else {}
    given = {**given, **source_options(base, **(source or {"loader": None}))}
    data = merge_options(base, given, "a sequence folder, a bag or sim:NAME")
    return apply_params(make_config(data), params)


@with_source_options
def run_command(
    dataset: Optional[str] = typer.Option(None, "--dataset", "-d", help=DATASET_HELP),
    sampler: Optional[str] = typer.Option(None, help=SAMPLER_HELP),
    descriptor: Optional[str] = typer.Option(None, help=DESCRIPTOR_HELP),
    odometry: Optional[str] = typer.Option(None, help="kiss (default) or a KITTI/TUM pose file"),
    mode: Optional[str] = typer.Option(None, help=MODE_HELP),
    param: list[str] = typer.Option([], "--param", "-p", help=PARAM_HELP),
    config: Optional[Path] = typer.Option(None, help="YAML config (e.g. a result's config.yaml)"),
    out: Optional[Path] = typer.Option(None, help=out_help("run")),
    overwrite: bool = typer.Option(False, "--overwrite", help=OVERWRITE_HELP),
    cache_dir: Optional[Path] = typer.Option(None, help=CACHE_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bars"),
    sweep: bool = typer.Option(
        False,
        "--sweep/--no-sweep",
        help="also replay the back-end at similarity "
        "thresholds 0.70-0.85 (an analysis, not part of the run: about half its time)",
    ),
    source: Optional[dict] = None,  # --loader, --gt, ... (added by with_source_options)
) -> None:
    """Run one sampler through the batch experiment and write its result folder; prints the path of its report.md."""
    from msa_slam.cli.config import cache_option
    from msa_slam.pipeline.driver import RUN_SWEEP_NOT_RUN, run
    from msa_slam.reporting.results import write_run

    given = {
        "dataset": dataset,
        "sampler": sampler,
        "descriptor": descriptor,
        "odometry": odometry,
        "mode": mode,
        "cache_dir": cache_option(cache_dir),
    }
    cfg = batch_config(config, given, param, source)
    sweeps = None
    if sweep:  # imported only then: the sweep's modules are not needed before the odometry starts
        from msa_slam.experiments.sweep import threshold_sweep

        sweeps = threshold_sweep
    report = write_run(
        lambda: run(
            cfg,
            quiet=quiet,
            sweep=sweeps,
            sweep_off=RUN_SWEEP_NOT_RUN,  # --out checked first,
            window_fix=WINDOW_FIX,
        ),
        out,
        "run",
        overwrite,
    )  # the window before any work
    typer.echo(str(report))
