"""`msa-slam compare`: the paper's method set on one sequence (Table I layout)."""

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
    out_help,
    reporting_failed_methods,
    with_source_options,
)

# What to change when MSA's window is longer than the frames read (pipeline.frontend.check_window): as for run
# (-p window reaches msa, experiments.compare.method_configs), except --sampler, which compare does not have
COMPARE_WINDOW_FIX = "use a window of at most {frames} frames (-p window={frames}) or -p flush=true"
COMPARE_PARAM_HELP = (
    PARAM_HELP + "; sampler parameters (window=8, sampler.lambda_u=5) go to msa, the baselines "
    "keep the paper's settings, except the standstill gate's (min_motion=0.1, min_rotation=0.5 "
    "by default; min_motion=0 switches it off), which go to every method but all"
)


@with_source_options
def compare_command(
    dataset: Optional[str] = typer.Option(None, "--dataset", "-d", help=DATASET_HELP),
    descriptor: Optional[str] = typer.Option(None, help=DESCRIPTOR_HELP),
    odometry: Optional[str] = typer.Option(None, help="kiss (default) or a KITTI/TUM pose file"),
    mode: Optional[str] = typer.Option(None, help=MODE_HELP),
    param: list[str] = typer.Option([], "--param", "-p", help=COMPARE_PARAM_HELP),
    config: Optional[Path] = typer.Option(
        None, help="YAML config (its sampler is replaced by the method set; its sampler parameters go to msa)"
    ),
    out: Optional[Path] = typer.Option(
        None,
        help=out_help("compare") + "; with --seeds, a previous run of the "
        "same settings is resumed (its finished seeds are reused; those whose data "
        "or code changed since are rerun)",
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help=OVERWRITE_HELP),
    cache_dir: Optional[Path] = typer.Option(None, help=CACHE_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bars"),
    seeds: Optional[str] = typer.Option(
        None,
        help="world seeds of a sim: dataset, e.g. 0,1,2: the comparison on "
        "each, then mean +- std, per-seed ranks and MSA's paired-test verdicts; "
        "each seed is kept when it finishes, so rerunning the same command on the "
        "same --out resumes an interrupted run",
    ),
    sweep: bool = typer.Option(
        True,
        "--sweep/--no-sweep",
        help="also replay each method's back-end at similarity thresholds 0.70-0.85 (about half of a method's time)",
    ),
    figures: bool = typer.Option(
        True,
        "--figures/--no-figures",
        help="draw the PNG figures (the comparison's and "
        "each method's); --no-figures writes only the tables and data files",
    ),
    workers: Optional[int] = typer.Option(
        None,
        "--workers",
        help="run the methods in N worker processes "
        "forked after the shared front end (default: one per CPU); 1 runs them "
        "one after another in this process. The files are identical either way, "
        "but for the measured times and memory",
    ),
    source: Optional[dict] = None,  # --loader, --gt, ... (added by with_source_options)
) -> None:
    """Run the paper's method set (all, constant 1/2/3 m, entropy, spaciousness, MSA) on one sequence and
    write the Table-I-style comparison; prints the path of its report.md (with --seeds, first the spread over
    seeds)."""
    from msa_slam.cli.config import cache_option
    from msa_slam.cli.run import batch_config
    from msa_slam.experiments.compare import MethodsFailed, check_compare_sampler, run_compare
    from msa_slam.experiments.seeds import parse_seeds
    from msa_slam.workers import available_cpus

    given = {
        "dataset": dataset,
        "descriptor": descriptor,
        "odometry": odometry,
        "mode": mode,
        "cache_dir": cache_option(cache_dir),
    }
    cfg = batch_config(config, given, param, source)
    check_compare_sampler(cfg)
    seed_list = None if seeds is None else parse_seeds(seeds)
    with reporting_failed_methods():
        try:  # run_compare checks --out, then (with the dataset opened once) the methods' windows, before any work
            report = run_compare(
                cfg,
                out,
                quiet=quiet,
                overwrite=overwrite,
                seeds=seed_list,
                sweep=sweep,
                window_fix=COMPARE_WINDOW_FIX,
                figures=figures,
                workers=available_cpus() if workers is None else workers,
            )
        except MethodsFailed as exc:  # the spread over the seeds that finished is still worth printing
            _echo_seeds(exc.report, seed_list)
            raise
        _echo_seeds(report, seed_list)
        typer.echo(str(report))


def _echo_seeds(report: Path, seeds: Optional[list[int]]) -> None:
    """Print the spread over seeds (seeds.md beside `report`) of a --seeds comparison."""
    if seeds is not None and (report.parent / "seeds.md").is_file():
        typer.echo((report.parent / "seeds.md").read_text())
