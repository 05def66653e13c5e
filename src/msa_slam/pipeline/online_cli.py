"""`msa-slam online`: the online (iSAM2) pipeline on one sequence, writing its result folder."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from msa_slam.pipeline.cli import OVERWRITE_HELP, out_help

ONLINE_DATASET_HELP = ("sequence folder, sim:NAME (cached on disk) or live:NAME[,field=value...,laps=K] "
                       "(simulated in memory, e.g. live:city-tour,laps=10)")
ONLINE_PARAM_HELP = ("override as key=value (repeatable): a config key (cloud_store=disk, max_frames=500), "
                     "a section field (verifier.max_residual=0.2), a stage parameter (sampler.lambda_u=5, "
                     "odometry.translation_noise=0.02) or a bare sampler parameter")


def apply_online_params(data: dict, params: List[str]):
    """`key=value` overrides (YAML values) on an online config mapping; returns a validated OnlineConfig."""
    from msa_slam.pipeline.config import apply_overrides
    from msa_slam.pipeline.online_config import OnlineConfig, make_online_config

    return make_online_config(apply_overrides(make_online_config(data).dump(), params, OnlineConfig))


def online_command(
    dataset: Optional[str] = typer.Option(None, "--dataset", "-d", help=ONLINE_DATASET_HELP),
    sampler: Optional[str] = typer.Option(None, help="all, constant, entropy, spaciousness, msa (default msa)"),
    descriptor: Optional[str] = typer.Option(None, help="sc (default), ot, precomputed"),
    odometry: Optional[str] = typer.Option(None, help="kiss (default), gt-noise, or a KITTI/TUM pose file"),
    mode: Optional[str] = typer.Option(None, help="oracle (default, the paper) or realistic"),
    cloud_store: Optional[str] = typer.Option(None, help="memory (default) or disk (keyframe clouds as .npy)"),
    param: List[str] = typer.Option([], "--param", "-p", help=ONLINE_PARAM_HELP),
    config: Optional[Path] = typer.Option(None, help="YAML config (e.g. an online result's config.yaml)"),
    out: Optional[Path] = typer.Option(None, help=out_help("online")),
    overwrite: bool = typer.Option(False, "--overwrite", help=OVERWRITE_HELP),
    cache_dir: Optional[Path] = typer.Option(None, help="cache root (default $MSA_SLAM_CACHE or ~/.cache/msa-slam)"),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
) -> None:
    """Run the online pipeline frame by frame (odometry, descriptor, sampler, loop detection, verification,
    iSAM2) and write its result folder; prints the path of its report.md."""
    import yaml

    from msa_slam.errors import InputError
    from msa_slam.pipeline.online import run_online
    from msa_slam.io.outputs import DEFAULT_RESULTS, open_result_folder
    from msa_slam.pipeline.online_results import write_online_files

    data = {}
    if config is not None:
        if not config.is_file():
            raise InputError(f"{config}: config file not found")
        data = yaml.safe_load(config.read_text()) or {}
        if not isinstance(data, dict):
            raise InputError(f"{config}: expected a mapping of config keys")
    given = {"dataset": dataset, "sampler": sampler, "descriptor": descriptor, "odometry": odometry, "mode": mode,
             "cloud_store": cloud_store, "cache_dir": None if cache_dir is None else str(cache_dir)}
    if sampler is not None and data.get("sampler") not in (None, sampler):
        data["sampler_params"] = {}
    data.update({k: v for k, v in given.items() if v is not None})
    if "dataset" not in data:
        raise InputError("--dataset is required (a sequence folder, sim:NAME or live:NAME), or give --config")
    cfg = apply_online_params(data, param)
    with open_result_folder(out, "online", DEFAULT_RESULTS / "online", overwrite=overwrite) as folder:
        result = run_online(cfg, quiet=quiet)
        with folder.staging() as tmp:
            write_online_files(result, tmp)
    typer.echo(str(folder.path / "report.md"))
