"""Every writer removes only what it can prove it wrote: a damaged simulation is repaired in place, a resumed
experiment keeps a user's folders, a glob character in --out touches no other run's work, and --out expands
`~` and refuses the working directory."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from helpers.cli import main_in_process
from test_experiments import TOO_SPARSE
from test_faults import cli, command, leftovers, stream_files  # noqa: F401 (stream_files: a fixture)
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.experiments import parse_grid, run_grid
from msa_slam.io.outputs import is_result_folder

SIM = ["simulate", "--trajectory", "kitti-07", "--end", "12", "--azimuth-steps", "360", "--quiet"]


def _killed_python(code: str, *args: str) -> None:
    """Run `code` in a new interpreter that ends with os._exit(9): a writer killed without any cleanup."""
    assert subprocess.run([sys.executable, "-c", code, *args]).returncode == 9


def test_damaged_simulation_is_repaired_in_place_keeping_user_files(tmp_path):
    seq = tmp_path / "S"
    assert CliRunner().invoke(app, [*SIM, "--out", str(seq)]).exit_code == 0
    scan, times = seq / "velodyne" / "000005.bin", seq / "velodyne_times" / "000007.npy"
    original_scan, original_times = scan.read_bytes(), times.read_bytes()
    untouched = (seq / "velodyne" / "000003.bin").stat()
    (seq / "my_analysis").mkdir()
    (seq / "my_analysis" / "notes.txt").write_text("mine")
    folder = seq.stat().st_ino
    scan.write_bytes(original_scan[:-16])
    times.unlink()

    rerun = CliRunner().invoke(app, [*SIM, "--out", str(seq)])
    assert rerun.exit_code == 0, rerun.output
    assert (seq / "my_analysis" / "notes.txt").read_text() == "mine"
    assert seq.stat().st_ino == folder  # repaired, not replaced
    assert scan.read_bytes() == original_scan and times.read_bytes() == original_times  # cast again: same bytes
    assert (seq / "velodyne" / "000003.bin").stat().st_ino == untouched.st_ino  # a sound scan is left as it is
    assert sorted(p.name for p in tmp_path.iterdir()) == ["S"]


def test_resumed_experiment_keeps_user_folders_and_removes_killed_writers_leftovers(tmp_path):
    grid, out = parse_grid(TOO_SPARSE), tmp_path / "E"
    run_grid(grid, out)  # a real experiment folder (its one cell fails fast)
    (out / "stores").mkdir()
    (out / "stores" / "mydata.txt").write_text("mine")
    (out / "cells" / ".mynotes.partial-keep").mkdir()
    (out / "cells" / ".mynotes.partial-keep" / "notes.txt").write_text("mine")
    _killed_python(
        "import os, sys; from pathlib import Path; from msa_slam.io.staging import staged_dir\n"
        "with staged_dir(Path(sys.argv[1])) as tmp:\n"
        "    (tmp / 'metrics.json').write_text('{'); os._exit(9)\n",
        str(out / "cells" / "cell-a"),
    )
    _killed_python(
        "import os, sys, numpy as np; from msa_slam.registration import DiskCloudStore\n"
        "store = DiskCloudStore(0.5, sys.argv[1]); store.add(1, np.ones((50, 3)) * np.arange(50)[:, None])\n"
        "os._exit(9)\n",
        str(out / "stores" / "cell-b"),
    )
    killed = [p for p in (out / "cells").iterdir() if p.name.startswith(".cell-a.partial-")]
    assert len(killed) == 1 and (out / "stores" / "cell-b").is_dir()

    run_grid(grid, out)
    assert (out / "stores" / "mydata.txt").read_text() == "mine"
    assert (out / "cells" / ".mynotes.partial-keep" / "notes.txt").read_text() == "mine"
    assert not killed[0].exists() and not (out / "stores" / "cell-b").exists()


def test_glob_characters_in_out_touch_no_other_run_and_its_own_leftovers_go(stream_files, monkeypatch, capsys):
    tmp, parent = stream_files, stream_files / "P"
    parent.mkdir()
    code = (
        "import sys; from pathlib import Path; from msa_slam.io.staging import staged_dir\n"
        "with staged_dir(Path(sys.argv[1]), 'compare') as tmp:\n"
        "    (tmp / 'report.md').write_text('cab'); print('ready', flush=True); sys.stdin.readline()\n"
    )
    compare = subprocess.Popen(
        [sys.executable, "-c", code, str(parent / "cab")], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert compare.stdout.readline().strip() == "ready"  # its .cab.partial-* is being written
        star = main_in_process(monkeypatch, capsys, *command("sample", tmp, parent / "c*", tmp / "cache"))
        assert star.returncode == 0, star.stderr
    finally:
        compare.communicate("\n", timeout=60)
    assert compare.returncode == 0 and (parent / "cab" / "report.md").read_text() == "cab"

    brackets = parent / "res[1]"
    args = command("sample", tmp, brackets, tmp / "cache")
    assert cli(tmp, "staging", args, tmp / "cache", brackets).returncode == -9
    assert leftovers(parent)  # a killed run's own staging folder and lock file
    assert main_in_process(monkeypatch, capsys, *args).returncode == 0
    assert leftovers(parent) == [] and is_result_folder(brackets)
    assert sorted(p.name for p in parent.iterdir()) == ["c*", "cab", "res[1]"]


def test_out_expands_the_home_folder(stream_files, monkeypatch):
    home = stream_files / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(stream_files)
    args = command("sample", stream_files, Path("~/samples"), stream_files / "cache")
    assert CliRunner().invoke(app, args).exit_code == 0
    assert CliRunner().invoke(app, [*SIM, "--end", "3", "--out", "~/sim"]).exit_code == 0
    assert is_result_folder(home / "samples") and (home / "sim" / "sim.json").is_file()
    assert not (stream_files / "~").exists()


def test_out_that_is_the_working_directory_or_a_parent_is_refused(stream_files, monkeypatch, capsys):
    empty = stream_files / "empty"
    empty.mkdir()
    folder = empty.stat().st_ino
    monkeypatch.chdir(empty)
    for out in (".", "..", str(empty)):
        refused = main_in_process(
            monkeypatch, capsys, *command("sample", stream_files, Path(out), stream_files / "cache")
        )
        (line,) = refused.stderr.strip().splitlines()
        assert refused.returncode == 2 and "current working directory; choose a new folder" in line, line
    assert empty.stat().st_ino == folder and list(empty.iterdir()) == []
    assert sorted(p.name for p in stream_files.iterdir()) == ["desc.npy", "empty", "poses.txt"]
