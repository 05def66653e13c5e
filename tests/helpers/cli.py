"""The console entry point in a fresh process, as a user runs it: the tests of what a command prints, writes and
refuses run it this way, so that its exit code and its last line are the real ones."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

CLI_CODE = "import sys; from msa_slam.cli import main; sys.argv = ['msa-slam', *sys.argv[1:]]; main()"


def run_cli(*args: str, cache: Path | None = None, timeout: float = 600, **options: Any) -> subprocess.CompletedProcess:
    """`msa-slam ARGS` (msa_slam.cli.main) in a fresh Python; output captured as text unless `stdout=` is given.
    `cache` is the run's MSA_SLAM_CACHE, so that a test sees what a first use costs and writes."""
    if cache is not None:
        options["env"] = {**os.environ, **options.get("env", {}), "MSA_SLAM_CACHE": str(cache)}
    if "stdout" not in options:
        options["capture_output"] = True
    return subprocess.run([sys.executable, "-c", CLI_CODE, *args], text=True, timeout=timeout, **options)


def run_on_scans(command: str, scans: Path, folder: Path, *args: str) -> subprocess.CompletedProcess:
    """`msa-slam COMMAND -d SCANS --mode realistic ARGS`, its output in folder/out and its cache in folder/cache:
    the set-up of the tests of what a command says or refuses on a short recording."""
    out, cache = str(folder / "out"), str(folder / "cache")
    return run_cli(command, "-d", str(scans), "--mode", "realistic", *args, "--out", out, "--cache-dir", cache)
