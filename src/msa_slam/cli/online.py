"""`msa-slam online`: the online (iSAM2) pipeline on one sequence, writing its result folder."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from msa_slam.cli.options import (
    CACHE_HELP,
    DESCRIPTOR_HELP,
    MODE_HELP,
    OVERWRITE_HELP,
    SAMPLER_HELP,
    WINDOW_FIX,
    out_help,
    with_source_options,
)

DATASET_HELP = (
    "sequence folder (any layout --loader lists), a ROS1/ROS2 bag, sim:NAME (cached on disk) or "
    "live:NAME[,field=value...,laps=K] (simulated in memory, e.g. live:city-tour,laps=10)"
)
PARAM_HELP = (
    "override as key=value (repeatable): a config key (cloud_store=disk, max_frames=500), "
    "a section field (verifier.max_residual=0.2), a stage parameter (sampler.lambda_u=5, "
    "odometry.translation_noise=0.02) or a bare sampler parameter"
)


@with_source_options
def online_command(
    dataset: Optional[str] = typer.Option(None, "--dataset", "-d", help=DATASET_HELP),
    sampler: Optional[str] = typer.Option(None, help=SAMPLER_HELP),
    descriptor: Optional[str] = typer.Option(None, help=DESCRIPTOR_HELP),
    odometry: Optional[str] = typer.Option(None, help="kiss (default), gt-noise, or a KITTI/TUM pose file"),
    mode: Optional[str] = typer.Option(None, help=MODE_HELP),
    cloud_store: Optional[str] = typer.Option(None, help="memory (default) or disk (keyframe clouds as .npy)"),
    param: list[str] = typer.Option([], "--param", "-p", help=PARAM_HELP),
    config: Optional[Path] = typer.Option(None, help="YAML config (e.g. an online result's config.yaml)"),
    out: Optional[Path] = typer.Option(None, help=out_help("online")),
    overwrite: bool = typer.Option(False, "--overwrite", help=OVERWRITE_HELP),
    cache_dir: Optional[Path] = typer.Option(None, help=CACHE_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="no progress bar"),
    viewer: bool = typer.Option(
        False,
        "--viewer",
        help="show the run live in Rerun (scan, odometry and optimised "
        "trajectories, keyframes, loops); needs pip install "
        "'msa-slam\\[viewer]'",
    ),  # \\[: a literal bracket in the help's rich markup
    viewer_save: Optional[Path] = typer.Option(
        None,
        "--viewer-save",
        help="save the live view as a Rerun recording (.rrd, replay with `rerun FILE`) instead of a window",
    ),
    source: Optional[dict] = None,  # --loader, --gt, ... (added by with_source_options)
) -> None:
    """Run the online pipeline frame by frame (odometry, descriptor, sampler, loop detection, verification,
    iSAM2) and write its result folder; prints the path of its report.md."""
    from msa_slam.cli.config import cache_option, merge_options, source_options
    from msa_slam.pipeline.config import OnlineConfig, apply_online_params, read_config_file
    from msa_slam.pipeline.driver import run
    from msa_slam.pipeline.live import LiveFrontEnd, open_recording
    from msa_slam.reporting.results import write_run

    live = viewer or viewer_save is not None
    if live:  # before any work: a missing rerun-sdk is one clear line
        from msa_slam.viz.live import LiveViewer, check_viewer

        check_viewer(viewer_save)
    base = read_config_file(config, OnlineConfig) if config is not None else {}
    assert source is not None, "with_source_options passes the source options"
    given = {
        "dataset": dataset,
        "sampler": sampler,
        "descriptor": descriptor,
        "odometry": odometry,
        "mode": mode,
        "cloud_store": cloud_store,
        "cache_dir": cache_option(cache_dir),
        **source_options(base, **source),
    }
    cfg = apply_online_params(merge_options(base, given, "a sequence folder, a bag, sim:NAME or live:NAME"), param)

    def online_run():
        recording = open_recording(cfg, quiet, WINDOW_FIX)  # its checks before any work
        view = LiveViewer(save=viewer_save) if live else None
        try:
            return run(cfg, LiveFrontEnd(recording, view), quiet=quiet)
        finally:
            if view is not None:
                view.close()

    typer.echo(str(write_run(online_run, out, "online", overwrite)))
