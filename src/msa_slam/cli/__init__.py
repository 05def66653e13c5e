"""The `msa-slam` command line: one module per command over the library.

Each command imports its library inside the function, so `msa-slam --help` loads typer and nothing heavy
(no numpy, gtsam, matplotlib, trimesh); the library never imports this package.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import warnings
from collections.abc import Iterator
from types import FrameType
from typing import Optional, TextIO

import typer

from msa_slam import __version__
from msa_slam.cli import compare, demo, experiment, online, report, reproduce, run, sample, simulate
from msa_slam.cli.options import WEIGHTS_EPILOG, Command, Group
from msa_slam.errors import InputError

app = typer.Typer(
    name="msa-slam",
    help="Informed keyframe sampling (Minimal Subset Approach) for LiDAR SLAM, with a measured back-end.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    cls=Group,
)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"msa-slam {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Optional[bool] = typer.Option(
        None, "--version", callback=_print_version, is_eager=True, help="print the version and exit"
    ),
) -> None:
    """msa-slam command line."""


app.command("simulate", cls=Command)(simulate.simulate_command)
app.command("run", cls=Command, epilog=WEIGHTS_EPILOG)(run.run_command)
app.command("compare", cls=Command, epilog=WEIGHTS_EPILOG)(compare.compare_command)
app.command("demo", cls=Command)(demo.demo_command)
app.command("sample", cls=Command)(sample.sample_command)
app.command("online", cls=Command, epilog=WEIGHTS_EPILOG)(online.online_command)
app.command("experiment", cls=Command)(experiment.experiment_command)
app.command("report", cls=Command)(report.report_command)
app.command("reproduce", cls=Command)(reproduce.reproduce_command)


def _stop_on_signal(signum: int, frame: FrameType | None) -> None:
    """SIGTERM (kill, a job scheduler, docker stop) and SIGHUP (the terminal or ssh session closed) unwind the
    stack as Ctrl-C does, so the same cleanup runs (the result folder's `.NAME.lock` and staging files are
    removed); the exit status is the shell's 128 + the signal number."""
    raise SystemExit(128 + signum)


def _handle_stop_signals() -> None:
    """Install _stop_on_signal for SIGTERM and SIGHUP, but not over a SIGHUP ignored on purpose (nohup)."""
    signal.signal(signal.SIGTERM, _stop_on_signal)
    if signal.getsignal(signal.SIGHUP) == signal.SIG_DFL:
        signal.signal(signal.SIGHUP, _stop_on_signal)


@contextlib.contextmanager
def _warnings_as_lines() -> Iterator[None]:
    """Python warnings as `warning: TEXT` lines, each text once: Python would add the source path and code line,
    and print a warning raised from two places (a sampler warns when told the stream's length and again at
    its end) twice."""
    seen: set[str] = set()

    def show(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: TextIO | None = None,
        line: str | None = None,
    ) -> None:
        text = str(message)
        if text not in seen:
            seen.add(text)
            typer.echo(f"warning: {text}", err=True)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def main() -> None:
    """Entry point: usage errors as click prints them; InputError and PermissionError as one clear line with
    exit code 2; warnings as one line each; SIGTERM and SIGHUP clean up as Ctrl-C does."""
    _handle_stop_signals()
    try:
        with _warnings_as_lines():
            app()
    except InputError as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)
    except PermissionError as exc:  # an unreadable input or unwritable output anywhere: name it, no traceback
        typer.echo(f"error: {exc.filename}: {str(exc.strerror or exc).lower()} (check its permissions)", err=True)
        sys.exit(2)
