"""Help texts and small helpers the commands share (kept here so the library holds no CLI wording)."""

from __future__ import annotations

import contextlib
from typing import Iterator

import typer

SAMPLER_NAMES = ("all", "constant", "entropy", "spaciousness", "msa")  # tests check: == the registry's names
SAMPLER_HELP = f"{', '.join(SAMPLER_NAMES)} (default msa)"
DESCRIPTOR_HELP = ("sc (Scan Context, default), ot (OverlapTransformer: needs torch and the authors' pretrained "
                   "weights pretrained_overlap_transformer.pth.tar, published at "
                   "https://drive.google.com/file/d/1FNrx9pcDa9NF7z8CFtuTWyauNkeSEFW4 via "
                   "github.com/haomo-ai/OverlapTransformer; pass -p descriptor.weights=FILE), precomputed "
                   "(-p descriptor.path=FILE.npy)")
MODE_HELP = "oracle (default, the paper; needs ground truth) or realistic"
DATASET_HELP = ("sequence folder (KITTI, MulRan, HeLiPR, Apollo, Newer College layout, or a folder of .bin/.pcd/.ply "
                "scans), a ROS1/ROS2 bag (.bag, bag folder, .db3, .mcap), or sim:NAME (sim:demo, sim:kitti-05,...)")
LOADER_NAMES = ("kitti", "mulran", "helipr", "apollo", "ncd", "rosbag", "folder")  # tests: == datasets.LOADERS
LOADER_HELP = ("how to read --dataset: auto (default: from its layout) or kitti (velodyne/*.bin), mulran "
               "(sensor_data/Ouster/*.bin + global_pose.csv), helipr (LiDAR/<sensor>/*.bin; --sequence <sensor>), "
               "apollo (pcds/*.pcd), ncd (Newer College raw_format/ouster_scan), rosbag (--topic), folder (scans)")
TOPIC_HELP = "PointCloud2 topic of a bag (needed when it has several)"
GT_HELP = "ground-truth pose file, LiDAR frame: KITTI (one pose a scan) or TUM (matched by time); optional"
GT_FORMAT_HELP = "format of --gt: auto (default: 12 values a line KITTI, 8 TUM), kitti or tum"
SEQUENCE_HELP = "sequence of a dataset root (KITTI root: 00..21; MulRan root: KAIST01; HeLiPR: the sensor)"
FIRST_HELP = "first scan to read (0-based)"
JUMP_HELP = "read every JUMP-th scan"
FRAMES_HELP = "read at most N scans"
# The source options run, online and compare share (typer takes one OptionInfo as several commands' default)
LOADER = typer.Option(None, "--loader", help=LOADER_HELP)
TOPIC = typer.Option(None, "--topic", help=TOPIC_HELP)
GT = typer.Option(None, "--gt", help=GT_HELP)
GT_FORMAT = typer.Option(None, "--gt-format", help=GT_FORMAT_HELP)
SEQUENCE = typer.Option(None, "--sequence", help=SEQUENCE_HELP)
FIRST = typer.Option(None, "--first", min=0, help=FIRST_HELP)
JUMP = typer.Option(None, "--jump", min=1, help=JUMP_HELP)
FRAMES = typer.Option(None, "-n", "--frames", min=1, help=FRAMES_HELP)
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
