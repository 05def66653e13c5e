"""`msa-slam run`, `msa-slam compare` and `msa-slam demo`: thin entry points over the batch pipeline."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Iterator, List, Optional

import typer

DATASET_HELP = "sequence folder (KITTI layout, scan folder) or sim:NAME (sim:demo, sim:test, sim:kitti-05,...)"
OVERWRITE_HELP = "replace a previous msa-slam result in --out (never anything msa-slam did not write)"


def out_help(command: str) -> str:
    """--out help text: what the default is and what is refused."""
    return (f"result folder (default: a new ./msa_slam_results/{command}/<date_time>, linked as latest); an existing "
            "folder must be empty or a previous result (with --overwrite)")


PARAM_HELP = ("override as key=value (repeatable): a config key (similarity_threshold=0.7), a section field "
              "(verifier.max_residual=0.2, graph.robust=cauchy), a stage parameter (sampler.lambda_u=5, "
              "odometry.max_range=80) or a bare sampler parameter")


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


def _config(config_file: Optional[Path], dataset: Optional[str], sampler: Optional[str],
            descriptor: Optional[str], odometry: Optional[str], mode: Optional[str],
            cache_dir: Optional[Path], params: List[str]):
    from msa_slam.errors import InputError
    from msa_slam.pipeline.config import apply_params, load_config, make_config

    base = load_config(config_file).dump() if config_file else {}
    given = {"dataset": dataset, "sampler": sampler, "descriptor": descriptor, "odometry": odometry,
             "mode": mode, "cache_dir": None if cache_dir is None else str(cache_dir)}
    data = {**base, **{k: v for k, v in given.items() if v is not None}}
    if sampler is not None and base.get("sampler") not in (None, sampler):
        data["sampler_params"] = {}
    if "dataset" not in data:
        raise InputError("--dataset is required (a sequence folder or sim:NAME), or give --config")
    return apply_params(make_config(data), params)


def run_command(
    dataset: Optional[str] = typer.Option(None, "--dataset", "-d", help=DATASET_HELP),
    sampler: Optional[str] = typer.Option(None, help="all, constant, entropy, spaciousness, msa (default msa)"),
    descriptor: Optional[str] = typer.Option(None, help="sc (default), ot, precomputed"),
    odometry: Optional[str] = typer.Option(None, help="kiss (default) or a KITTI/TUM pose file"),
    mode: Optional[str] = typer.Option(None, help="oracle (default, the paper) or realistic"),
    param: List[str] = typer.Option([], "--param", "-p", help=PARAM_HELP),
    config: Optional[Path] = typer.Option(None, help="YAML config (e.g. a result's config.yaml)"),
    out: Optional[Path] = typer.Option(None, help=out_help("run")),
    overwrite: bool = typer.Option(False, "--overwrite", help=OVERWRITE_HELP),
    cache_dir: Optional[Path] = typer.Option(None, help="cache root (default $MSA_SLAM_CACHE or ~/.cache/msa-slam)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bars"),
) -> None:
    """Run one sampler through the batch experiment and write its result folder; prints its report.md."""
    from msa_slam.io.outputs import DEFAULT_RESULTS, open_result_folder
    from msa_slam.pipeline.batch import run_batch
    from msa_slam.pipeline.results import write_run_files

    cfg = _config(config, dataset, sampler, descriptor, odometry, mode, cache_dir, param)
    with open_result_folder(out, "run", DEFAULT_RESULTS / "run", overwrite=overwrite) as folder:
        result = run_batch(cfg, quiet=quiet)
        with folder.staging() as tmp:
            write_run_files(result, tmp)
    typer.echo(str(folder.path / "report.md"))


def compare_command(
    dataset: Optional[str] = typer.Option(None, "--dataset", "-d", help=DATASET_HELP),
    descriptor: Optional[str] = typer.Option(None, help="sc (default), ot, precomputed"),
    odometry: Optional[str] = typer.Option(None, help="kiss (default) or a KITTI/TUM pose file"),
    mode: Optional[str] = typer.Option(None, help="oracle (default, the paper) or realistic"),
    param: List[str] = typer.Option([], "--param", "-p", help=PARAM_HELP),
    config: Optional[Path] = typer.Option(None, help="YAML config (its sampler is replaced by the method set)"),
    out: Optional[Path] = typer.Option(None, help=out_help("compare")),
    overwrite: bool = typer.Option(False, "--overwrite", help=OVERWRITE_HELP),
    cache_dir: Optional[Path] = typer.Option(None, help="cache root (default $MSA_SLAM_CACHE or ~/.cache/msa-slam)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bars"),
) -> None:
    """Run the paper's method set (all, constant 1/2/3 m, entropy, spaciousness, MSA) on one sequence and
    write the Table-I-style comparison; prints its report.md."""
    from msa_slam.pipeline.compare import run_compare

    cfg = _config(config, dataset, None, descriptor, odometry, mode, cache_dir, param)
    with reporting_failed_methods():
        typer.echo(str(run_compare(cfg, out, quiet=quiet, overwrite=overwrite)))


def demo_command(
    out: Optional[Path] = typer.Option(None, help=out_help("demo")),
    overwrite: bool = typer.Option(False, "--overwrite", help=OVERWRITE_HELP),
    cache_dir: Optional[Path] = typer.Option(None, help="cache root (default $MSA_SLAM_CACHE or ~/.cache/msa-slam)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bars"),
) -> None:
    """The main job: compare all samplers on the embedded simulated KITTI-05 sequence (simulated and
    processed with KISS-ICP on first use, then cached); prints the path of its report.md."""
    from msa_slam.demo import run_demo

    with reporting_failed_methods():
        report = run_demo(out, cache_dir=cache_dir, quiet=quiet, overwrite=overwrite)
        typer.echo(f"report: {report}")
