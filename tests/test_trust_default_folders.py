"""Default (timestamped) result folders: two runs in the same second get two folders, what killed default
runs left is removed by the next run into the same parent (only what is provably msa-slam's, its writer
dead), and SIGHUP cleans up as SIGTERM does."""

from __future__ import annotations

import signal
import time
from pathlib import Path

from test_faults import cli, command, leftovers, stream_files  # noqa: F401 (stream_files: a fixture)

from msa_slam.io.outputs import is_result_folder, open_result_folder, staged_dir

STEM = "2026-01-01_00-00-00"


def default_sample(tmp: Path) -> list[str]:
    """The `sample` command of test_faults without --out: its result goes to msa_slam_results/sample/<time>."""
    args = command("sample", tmp, tmp / "unused", tmp / "cache")
    at = args.index("--out")
    return args[:at] + args[at + 2 :]


def test_two_default_runs_in_the_same_second_get_two_folders(tmp_path, monkeypatch):
    monkeypatch.setattr(time, "strftime", lambda *args: STEM)
    parent = tmp_path / "results"
    with open_result_folder(None, "sample", parent) as first:
        with open_result_folder(None, "sample", parent) as second, second.staging() as tmp:
            (tmp / "run.txt").write_text("second")
        with first.staging() as tmp:
            (tmp / "run.txt").write_text("first")
    assert (first.path.name, second.path.name) == (STEM, f"{STEM}-2")
    assert [(parent / name / "run.txt").read_text() for name in (STEM, f"{STEM}-2")] == ["first", "second"]
    assert sorted(p.name for p in parent.iterdir()) == [STEM, f"{STEM}-2", "latest"]


def test_leftovers_of_killed_default_runs_are_removed_by_the_next_one(stream_files):
    tmp = stream_files
    parent = tmp / "msa_slam_results" / "sample"
    killed = cli(tmp, "staging", default_sample(tmp), tmp / "cache", tmp / "unused")  # while writing its result
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    left = leftovers(parent)
    assert any(".partial-" in name for name in left) and any(name.endswith(".lock") for name in left)
    lookalikes = {parent / ".mine.partial-1" / "notes.txt": "mine", parent / ".mine.lock": "my lock"}
    for path, text in lookalikes.items():
        path.parent.mkdir(exist_ok=True)
        path.write_text(text)
    with staged_dir(parent / "live") as live:  # a writer at work (this process): its staging folder stays
        rerun = cli(tmp, "none", default_sample(tmp), tmp / "cache", tmp / "unused")
        assert rerun.returncode == 0, rerun.stderr
        assert live.is_dir()
    assert all(path.read_text() == text for path, text in lookalikes.items())
    assert sorted(leftovers(parent)) == sorted(str(p) for p in (parent / ".mine.lock", parent / ".mine.partial-1"))
    runs = [p for p in parent.iterdir() if not p.name.startswith(".") and p.name not in ("latest", "live")]
    assert len(runs) == 1 and is_result_folder(runs[0], "sample")


def test_sighup_cleans_up_as_sigterm_does(stream_files, monkeypatch):
    tmp = stream_files
    monkeypatch.setenv("MSA_FAULT_SIGNAL", "SIGHUP")
    hung_up = cli(tmp, "staging", default_sample(tmp), tmp / "cache", tmp / "unused")
    assert hung_up.returncode == 128 + signal.SIGHUP, hung_up.stderr
    assert leftovers(tmp) == [] and not (tmp / "msa_slam_results").exists()
