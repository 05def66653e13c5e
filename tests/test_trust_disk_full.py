"""A full disk mid-write is one line naming the folder on every write path (result folders, simulations, the
cache, atomic writes), also when the failing write raises an OSError without errno (numpy's tofile), and
nothing half-written stays behind."""

from __future__ import annotations

import errno
import logging
import os
import re
import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from helpers.cli import main_in_process
from test_faults import cli, command, leftovers, stream_files  # noqa: F401 (stream_files: a fixture)

import msa_slam.sampling.figure
import msa_slam.sim.sequence
from msa_slam.io.atomic import write_text_atomic
from msa_slam.io.cache import CacheDir
from msa_slam.io.outputs import OutputError

SHORT_WRITE = OSError("1835008 requested and 0 written")  # what numpy's tofile raises: no errno


@pytest.fixture
def full_disk(monkeypatch) -> None:
    """Every file system reports nothing free (as after a write that filled it)."""
    monkeypatch.setattr(shutil, "disk_usage", lambda path: SimpleNamespace(total=2**30, used=2**30, free=0))


def run_cli(monkeypatch, capsys, args: list[str]) -> tuple[int, list[str]]:
    """The msa-slam entry point in this process: its exit status and its stderr lines."""
    result = main_in_process(monkeypatch, capsys, *args)
    return result.returncode, result.stderr.strip().splitlines()


def test_simulation_short_write_on_a_full_disk_is_one_line(tmp_path, monkeypatch, capsys, full_disk):
    real = msa_slam.sim.sequence._write_scan

    def fill_the_disk(sim, target, k):
        if k == 2:
            raise SHORT_WRITE
        return real(sim, target, k)

    monkeypatch.setattr(msa_slam.sim.sequence, "_write_scan", fill_the_disk)
    out = tmp_path / "S"
    code, err = run_cli(
        monkeypatch,
        capsys,
        ["simulate", "--trajectory", "kitti-07", "--end", "6", "--azimuth-steps", "360", "--out", str(out), "--quiet"],
    )
    assert code == 2 and len(err) == 1
    assert re.fullmatch(
        rf"error: {re.escape(str(out))}: no space left on the device \(0\.0 MiB free; at least "
        r"0\.[1-9] MiB needed\); free some space or choose a writable --out or cache folder "
        r"\(MSA_SLAM_CACHE\)",
        err[0],
    ), err[0]
    assert list(tmp_path.iterdir()) == []


def test_result_folder_short_write_on_a_full_disk_is_one_line(stream_files, monkeypatch, capsys, full_disk):
    def fill_the_disk(*args, **kwargs):
        raise SHORT_WRITE

    monkeypatch.setattr(msa_slam.sampling.figure, "plot_keyframes", fill_the_disk)
    out = stream_files / "results" / "out"
    code, err = run_cli(monkeypatch, capsys, command("sample", stream_files, out, stream_files / "cache"))
    assert code == 2 and len(err) == 1
    assert err[0].startswith(f"error: {out}: no space left on the device (0.0 MiB free; at least ")
    assert not (stream_files / "results").exists()


@pytest.mark.parametrize(
    "failure, message",
    [
        (
            SHORT_WRITE,
            r"no space left on the device \(0\.0 MiB free; at least 0\.0 MiB needed\); free some space or "
            "choose another --out$",
        ),
        (OSError(errno.EDQUOT, os.strerror(errno.EDQUOT)), "no space left on the device"),
        (PermissionError(errno.EACCES, os.strerror(errno.EACCES)), r"cannot write there \(.*: permission denied\)"),
        (OSError(errno.EIO, os.strerror(errno.EIO)), r"cannot write there \(.*: input/output error\)"),
    ],
)
def test_atomic_write_failure_is_one_line_and_leaves_no_temp(tmp_path, monkeypatch, full_disk, failure, message):
    def fail(path, text):
        Path(path).open("w").close()  # the temporary file exists when the write fails
        failure.filename = failure.filename if failure.errno is None else str(path)
        raise failure

    monkeypatch.setattr(Path, "write_text", fail)
    with pytest.raises(OutputError, match=f"^{tmp_path / 'report.md'}: {message}"):
        write_text_atomic(tmp_path / "report.md", "# report\n")
    assert list(tmp_path.iterdir()) == []


def test_cache_short_write_on_a_full_disk_warns_once_naming_the_cause(tmp_path, monkeypatch, caplog, full_disk):
    def fill_the_disk(handle, array):
        raise SHORT_WRITE

    store = CacheDir(tmp_path)
    monkeypatch.setattr(np, "save", fill_the_disk)
    with caplog.at_level(logging.WARNING):
        assert store.save("a", np.zeros(10)) is None and store.save("b", np.zeros(10)) is None
    assert [r.getMessage() for r in caplog.records] == [
        f"cache: cannot write {tmp_path / 'a.npy'} (No space left on device; needs 0.00 MiB); "
        "continuing without the cache"
    ]
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def tiny_disk(tmp_path):
    """A 2 MiB tmpfs mounted for the test (skipped where mounting is not permitted)."""
    mount = tmp_path / "tiny"
    mount.mkdir()
    if (
        os.geteuid() != 0
        or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount)], capture_output=True
        ).returncode
        != 0
    ):
        pytest.skip("mounting a tmpfs is not permitted here")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=True)


def test_simulation_on_a_really_full_disk_is_one_line(tiny_disk, tmp_path):
    out = tiny_disk / "S"
    args = ["simulate", "--trajectory", "kitti-07", "--end", "12", "--out", str(out), "--quiet"]
    full = cli(tmp_path, "none", args, tmp_path / "cache", out)
    assert full.returncode == 2, full.stderr
    (line,) = full.stderr.strip().splitlines()
    assert re.fullmatch(
        rf"error: {re.escape(str(out))}: no space left on the device \(\d+\.\d MiB free; at least "
        r"\d+\.\d MiB needed\); free some space or choose a writable --out or cache folder "
        r"\(MSA_SLAM_CACHE\)",
        line,
    ), line
    assert list(tiny_disk.iterdir()) == [] and leftovers(tiny_disk) == []
