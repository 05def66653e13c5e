"""Help texts and small helpers the commands share (kept here so the library holds no CLI wording)."""

from __future__ import annotations

import contextlib
import functools
import inspect
import typing
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

import typer
from typer.core import TyperCommand, TyperGroup

if TYPE_CHECKING:  # typer runs its own copy of click (typer._click), whose types it does not re-export
    from typer._click import Context, Parameter


def _flags_take_no_value(params: list[Parameter]) -> list[Parameter]:
    """typer's rich help prints a value type (`<bool>`) beside flags, which take no value (plain click prints
    none): an empty metavar for each flag, the help option's included, leaves that column blank."""
    for param in params:
        if getattr(param, "is_flag", False):
            param.metavar = ""
    return params


class Command(TyperCommand):
    """A command whose --help shows no value type beside its flags."""

    def get_params(self, ctx: Context) -> list[Parameter]:
        return _flags_take_no_value(super().get_params(ctx))


class Group(TyperGroup):
    """The command group, whose --help shows no value type beside its flags (--version, --help)."""

    def get_params(self, ctx: Context) -> list[Parameter]:
        return _flags_take_no_value(super().get_params(ctx))


SAMPLER_NAMES = ("all", "constant", "entropy", "spaciousness", "msa")  # tests check: == the registry's names
SAMPLER_HELP = f"{', '.join(SAMPLER_NAMES)} (default msa)"
DESCRIPTOR_HELP = (
    "sc (Scan Context, default), ot (OverlapTransformer: needs torch and the authors' pretrained "
    "weights, -p weights=FILE; where to get them: the end of this help), precomputed "
    "(-p descriptor.path=FILE.npy)"
)
# After the options, a paragraph per line as wide as the terminal: a URL in an option's narrow help column would
# be cut (descriptors.overlap_transformer.WEIGHTS_URL, not imported: --help must not load numpy)
WEIGHTS_EPILOG = (
    "OverlapTransformer weights (--descriptor ot -p weights=FILE): the authors' "
    "pretrained_overlap_transformer.pth.tar, published at\n\n"
    "https://drive.google.com/file/d/1FNrx9pcDa9NF7z8CFtuTWyauNkeSEFW4\n\n"
    "via github.com/haomo-ai/OverlapTransformer."
)
MODE_HELP = "oracle (default, the paper; needs ground truth) or realistic"
DATASET_HELP = (
    "sequence folder (KITTI, MulRan, HeLiPR, Apollo, Newer College layout, or a folder of .bin/.pcd/.ply "
    "scans), a ROS1/ROS2 bag (.bag, bag folder, .db3, .mcap), or sim:NAME (sim:demo, sim:kitti-05,...)"
)
LOADER_NAMES = ("kitti", "mulran", "helipr", "apollo", "ncd", "rosbag", "folder")  # tests: == datasets.LOADERS
LOADER_HELP = (
    "how to read --dataset: auto (default: from its layout) or kitti (velodyne/*.bin), mulran "
    "(sensor_data/Ouster/*.bin + global_pose.csv), helipr (LiDAR/<sensor>/*.bin; --sequence <sensor>), "
    "apollo (pcds/*.pcd), ncd (Newer College raw_format/ouster_scan), rosbag (--topic), folder (scans)"
)
TOPIC_HELP = "PointCloud2 topic of a bag (needed when it has several)"
GT_HELP = "ground-truth pose file, LiDAR frame: KITTI (one pose a scan) or TUM (matched by time); optional"
GT_FORMAT_HELP = "format of --gt: auto (default: 12 values a line KITTI, 8 TUM), kitti or tum"
SEQUENCE_HELP = "sequence of a dataset root (KITTI root: 00..21; MulRan root: KAIST01; HeLiPR: the sensor)"
FIRST_HELP = "first scan to read (0-based)"
JUMP_HELP = "read every JUMP-th scan"
FRAMES_HELP = "read at most N scans"
# The source options run, online and compare share: name -> (type, option), in --help order after --dataset
SOURCE_OPTIONS: dict[str, tuple[Any, Any]] = {
    "loader": (Optional[str], typer.Option(None, "--loader", help=LOADER_HELP)),
    "topic": (Optional[str], typer.Option(None, "--topic", help=TOPIC_HELP)),
    "gt": (Optional[Path], typer.Option(None, "--gt", help=GT_HELP)),
    "gt_format": (Optional[str], typer.Option(None, "--gt-format", help=GT_FORMAT_HELP)),
    "sequence": (Optional[str], typer.Option(None, "--sequence", help=SEQUENCE_HELP)),
    "first": (Optional[int], typer.Option(None, "--first", min=0, help=FIRST_HELP)),
    "jump": (Optional[int], typer.Option(None, "--jump", min=1, help=JUMP_HELP)),
    "frames": (Optional[int], typer.Option(None, "-n", "--frames", min=1, help=FRAMES_HELP)),
}


def with_source_options(command: Callable[..., None]) -> Callable[..., None]:
    """`command` with the source options (SOURCE_OPTIONS) added after its --dataset; it receives them as
    one `source` mapping (its own `source` parameter is hidden from the command line). One declaration for
    run, compare and online instead of eight repeated parameters each."""
    signature = inspect.signature(command)
    hints = typing.get_type_hints(command)  # real types: the command's module may postpone annotations
    own = [
        p.replace(annotation=hints.get(name, p.annotation))
        for name, p in signature.parameters.items()
        if name != "source"
    ]
    added = [
        inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=option, annotation=kind)
        for name, (kind, option) in SOURCE_OPTIONS.items()
    ]
    at = next(i for i, p in enumerate(own) if p.name == "dataset") + 1
    params = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in own]
    params[at:at] = added

    @functools.wraps(command)
    def wrapper(**kwargs: Any) -> None:
        source = {name: kwargs.pop(name) for name in SOURCE_OPTIONS}
        return command(source=source, **kwargs)

    wrapper.__signature__ = signature.replace(parameters=params, return_annotation=None)  # type: ignore[attr-defined]
    wrapper.__annotations__ = {p.name: p.annotation for p in params} | {"return": None}
    del wrapper.__wrapped__  # typer must read the new signature, not the wrapped one
    return wrapper


# What to change when the sampler's window is longer than the frames read (cli.config.check_window: `frames`, `window`)
WINDOW_FIX = "use a window of at most {frames} frames (-p window={frames}), -p flush=true or --sampler all"

OVERWRITE_HELP = "replace a previous msa-slam result in --out (never anything msa-slam did not write)"
CACHE_HELP = "cache root (default $MSA_SLAM_CACHE or ~/.cache/msa-slam)"
PARAM_HELP = (
    "override as key=value (repeatable): a config key (similarity_threshold=0.7), a section field "
    "(verifier.max_residual=0.2, graph.robust=cauchy), a stage parameter (sampler.lambda_u=5, "
    "odometry.max_range=80) or a bare sampler parameter, or weights=FILE "
    "(the OverlapTransformer's, with --descriptor ot)"
)


def out_help(command: str) -> str:
    """--out help text: what the default is and what is refused."""
    return (
        f"result folder (default: a new ./msa_slam_results/{command}/<date_time>, linked as latest); an existing "
        "folder must be empty or a previous result (with --overwrite)"
    )


@contextlib.contextmanager
def reporting_failed_methods() -> Iterator[None]:
    """A comparison with failed methods: print its report path and one line per failure, exit 1."""
    from msa_slam.experiments.compare import MethodsFailed

    try:
        yield
    except MethodsFailed as exc:
        typer.echo(str(exc.report))
        for name, error in exc.failed.items():
            typer.echo(f"failed: {name}: {error}", err=True)
        raise typer.Exit(1) from None
