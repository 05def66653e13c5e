"""The console entry point in a fresh process, as a user runs it, so that its exit code and its last line are the
real ones; or in the test's own process, for the tests of a refusal or failure whose text is what they check."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

CLI_CODE = "import sys; from msa_slam.cli import main; sys.argv = ['msa-slam', *sys.argv[1:]]; main()"


def run_cli(*args: str, cache: Path | None = None, timeout: float = 600, **options: Any) -> subprocess.CompletedProcess:
    """`msa-slam ARGS` (msa_slam.cli.main) in a fresh Python; output captured as text unless `stdout=` is given.
    `cache` is the run's MSA_SLAM_CACHE, so that a test sees what a first use costs and writes."""
    if cache is not None:
        options["env"] = {**os.environ, **options.get("env", {}), "MSA_SLAM_CACHE": str(cache)}
    if "stdout" not in options:
        options["capture_output"] = True
    return subprocess.run([sys.executable, "-c", CLI_CODE, *args], text=True, timeout=timeout, **options)


def on_scans(command: str, scans: Path, folder: Path, *args: str) -> list[str]:
    """The arguments of `msa-slam COMMAND -d SCANS --mode realistic ARGS`, its output in folder/out and its cache
    in folder/cache: the set-up of the tests of what a command says or refuses on a short recording."""
    out, cache = str(folder / "out"), str(folder / "cache")
    return [command, "-d", str(scans), "--mode", "realistic", *args, "--out", out, "--cache-dir", cache]


def run_on_scans(command: str, scans: Path, folder: Path, *args: str) -> subprocess.CompletedProcess:
    """on_scans' command in a fresh process."""
    return run_cli(*on_scans(command, scans, folder, *args))


def main_in_process(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, *args: str
) -> subprocess.CompletedProcess:
    """`msa-slam ARGS` through msa_slam.cli.main in this process, its exit status and output as run_cli gives them:
    for the tests of a refusal or failure whose text, not the process, is checked (a fresh process costs seconds
    of imports; test_cli_main.py checks that one has the same one line). The SIGTERM and SIGHUP handlers main
    installs are put back."""
    from msa_slam.cli import main

    handlers = {signum: signal.getsignal(signum) for signum in (signal.SIGTERM, signal.SIGHUP)}
    monkeypatch.setattr(sys, "argv", ["msa-slam", *args])
    try:
        with pytest.raises(SystemExit) as stopped:
            main()
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
    captured = capsys.readouterr()
    return subprocess.CompletedProcess(list(args), stopped.value.code, captured.out, captured.err)
