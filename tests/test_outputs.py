"""Result folders: msa-slam never removes or replaces what it did not write, and results appear atomically."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.errors import InputError
from msa_slam.io.outputs import MARKER, OutputError, is_result_folder, open_result_folder, staged_dir, write_marker
from msa_slam.io.staging import WRITER, stamp

runner = CliRunner()


def tree(path: Path) -> dict[str, bytes]:
    """Every file under `path` with its bytes (the state a command must leave untouched)."""
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.fixture
def user_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "thesis"
    (folder / "sub").mkdir(parents=True)
    (folder / "thesis.tex").write_text("\\documentclass{article}\n")
    (folder / "sub" / "a.bin").write_bytes(b"\x00\x01\x02")
    return folder


@pytest.fixture
def stream(tmp_path: Path) -> tuple[Path, Path]:
    """A small pose file and descriptors for `msa-slam sample` (cheap to run)."""
    rng = np.random.default_rng(0)
    poses = np.tile(np.eye(4), (30, 1, 1))
    poses[:, 0, 3] = np.arange(30) * 1.5
    (tmp_path / "poses.txt").write_text("".join(" ".join(f"{v:.6f}" for v in p[:3].ravel()) + "\n" for p in poses))
    np.save(tmp_path / "desc.npy", rng.random((30, 8)))
    return tmp_path / "poses.txt", tmp_path / "desc.npy"


def sample(stream, *extra) -> object:
    poses, desc = stream
    return runner.invoke(
        app,
        ["sample", "--poses", str(poses), "--descriptors", str(desc), "-p", "window=5", "--quiet", *map(str, extra)],
    )


@pytest.mark.parametrize(
    "command",
    [
        ["run", "--dataset", "sim:test"],
        ["compare", "--dataset", "sim:test"],
        ["online", "--dataset", "sim:test"],
        ["demo"],
    ],
)
def test_pipeline_commands_refuse_a_user_folder_before_any_work(command, user_folder, tmp_path):
    before = tree(user_folder)
    result = runner.invoke(
        app, [*command, "--out", str(user_folder), "--cache-dir", str(tmp_path / "cache"), "--quiet"]
    )
    assert isinstance(result.exception, OutputError), result.output
    assert "is not a msa-slam result folder" in str(result.exception)
    assert tree(user_folder) == before
    assert not (tmp_path / "cache").exists()  # refused before the dataset was even simulated


def test_a_dataset_folder_and_a_file_are_refused(tmp_path, stream):
    dataset = tmp_path / "seq"
    (dataset / "velodyne").mkdir(parents=True)
    (dataset / "velodyne" / "000000.bin").write_bytes(np.zeros(16, np.float32).tobytes())
    before = tree(dataset)
    result = runner.invoke(app, ["run", "--dataset", str(dataset), "--out", str(dataset), "--quiet"])
    assert isinstance(result.exception, OutputError) and tree(dataset) == before
    target = tmp_path / "notes.txt"
    target.write_text("mine")
    result = sample(stream, "--out", target)
    assert "is a file, not a result folder" in str(result.exception)
    assert target.read_text() == "mine"


def test_previous_result_is_replaced_only_with_overwrite(stream, tmp_path):
    out = tmp_path / "out"
    assert sample(stream, "--out", out).exit_code == 0
    assert is_result_folder(out, "sample")
    first = tree(out)
    result = sample(stream, "--out", out, "-p", "lambda_u=2")
    assert "pass --overwrite" in str(result.exception)
    assert tree(out) == first
    assert sample(stream, "--out", out, "-p", "lambda_u=2", "--overwrite").exit_code == 0
    assert tree(out) != first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["desc.npy", "out", "poses.txt"]  # no leftovers


def test_overwrite_never_removes_a_file_msa_slam_did_not_write(stream, tmp_path):
    out = tmp_path / "out"
    assert sample(stream, "--out", out).exit_code == 0
    (out / "notes.md").write_text("mine")
    (out / "plots").mkdir()
    (out / "plots" / "p.txt").write_text("mine too")
    first = tree(out)
    result = sample(stream, "--out", out, "-p", "lambda_u=2", "--overwrite")
    assert result.exit_code != 0
    assert "holds files msa-slam did not write (notes.md, plots/p.txt)" in str(result.exception)
    assert tree(out) == first


def test_overwrite_never_loses_a_users_edit_of_a_file_msa_slam_wrote(stream, tmp_path):
    out = tmp_path / "out"
    assert sample(stream, "--out", out).exit_code == 0
    (out / "keyframes.txt").write_text((out / "keyframes.txt").read_text() + "# checked by hand\n")
    first = tree(out)
    result = sample(stream, "--out", out, "-p", "lambda_u=2", "--overwrite")
    assert result.exit_code != 0
    assert "holds files changed since msa-slam wrote them (keyframes.txt)" in str(result.exception)
    assert tree(out) == first
    (out / "keyframes.txt").write_text(first["keyframes.txt"].decode().replace("# checked by hand\n", ""))
    assert sample(stream, "--out", out, "-p", "lambda_u=2", "--overwrite").exit_code == 0  # restored: ours again


def test_empty_folder_is_taken(stream, tmp_path):
    out = tmp_path / "empty"
    out.mkdir()
    assert sample(stream, "--out", out).exit_code == 0
    assert (out / "keyframes.txt").is_file() and (out / MARKER).is_file()


def test_default_output_is_a_new_timestamped_folder_with_latest_link(stream, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert sample(stream).exit_code == 0
    assert sample(stream).exit_code == 0
    parent = tmp_path / "msa_slam_results" / "sample"
    runs = sorted(p for p in parent.iterdir() if not p.is_symlink())
    assert len(runs) == 2 and all(is_result_folder(p, "sample") for p in runs)
    latest = parent / "latest"
    assert latest.is_symlink() and latest.resolve() == runs[-1].resolve()


def test_a_second_run_on_the_same_out_refuses_while_the_first_holds_it(stream, tmp_path):
    out = tmp_path / "out"
    with open_result_folder(out, "sample", tmp_path) as folder:
        result = sample(stream, "--out", out)
        assert "another msa-slam run is writing" in str(result.exception)
        with folder.staging() as tmp:
            (tmp / "first.txt").write_text("first")
    assert (out / "first.txt").read_text() == "first"
    assert not (tmp_path / ".out.lock").exists()


def test_failed_block_leaves_old_result_and_no_partials(tmp_path):
    out = tmp_path / "out"
    with open_result_folder(out, "run", tmp_path) as folder, folder.staging() as tmp:
        (tmp / "a.txt").write_text("old")
    with pytest.raises(RuntimeError):
        with open_result_folder(out, "run", tmp_path, overwrite=True) as folder, folder.staging() as tmp:
            (tmp / "a.txt").write_text("new")
            raise RuntimeError("killed in the middle")
    assert (out / "a.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_leftovers_of_a_killed_swap_are_repaired(tmp_path):
    """A kill between the two renames of a swap left the old result aside and --out missing."""
    displaced = tmp_path / ".out.old-123-456"
    displaced.mkdir()
    (displaced / "a.txt").write_text("old")
    write_marker(displaced, "run")  # after: it lists a.txt as msa-slam's
    partial = tmp_path / ".out.partial-abc"
    partial.mkdir()
    (partial / "half.txt").write_text("half")
    (partial / WRITER).write_bytes(stamp())  # what a killed writer leaves: its stamp, no longer locked
    with open_result_folder(tmp_path / "out", "run", tmp_path, overwrite=True):
        assert (tmp_path / "out" / "a.txt").read_text() == "old"  # restored before anything else
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_results_respect_the_umask(stream, tmp_path):
    old = os.umask(0o022)
    try:
        assert sample(stream, "--out", tmp_path / "out").exit_code == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "out").stat().st_mode) == 0o755
    assert stat.S_IMODE((tmp_path / "out" / "keyframes.json").stat().st_mode) == 0o644


def test_full_disk_is_one_line_naming_the_path(tmp_path):
    target = tmp_path / "out"
    with pytest.raises(OutputError, match=r"out: no space left on the device \(.* MiB free; at least .* MiB needed\)"):
        with staged_dir(target, "run") as tmp:
            (tmp / "big.bin").write_bytes(b"\x00" * 4096)
            raise OSError(errno.ENOSPC, "No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_unwritable_parent_is_refused_before_work(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError, match="cannot write there"):
        with open_result_folder(blocker / "out", "run", tmp_path):
            pass


def _grow(out: Path, tmp_path: Path, units: dict[str, str], overwrite: bool = False) -> None:
    """One run of a folder that grows in place (as experiment grids do): writes the `units` (cells/<name> with
    its cell.json and `x.txt` holding the text) and rewrites report.md."""
    with open_result_folder(out, "experiment", tmp_path, overwrite=overwrite, resume=True) as folder:
        folder.prepare_in_place(fresh=overwrite, grows=("cells",), unit_record="cell.json")
        (out / "cells").mkdir(exist_ok=True)
        for name, text in units.items():
            with staged_dir(out / "cells" / name) as tmp:
                (tmp / "cell.json").write_text("{}")
                (tmp / "x.txt").write_text(text)
        (out / "report.md").write_text(f"cells: {sorted(p.name for p in (out / 'cells').iterdir())}\n")
        folder.record_files()


def test_a_folder_grown_in_place_never_takes_a_users_files_or_edits_for_its_own(tmp_path):
    out = tmp_path / "exp"
    _grow(out, tmp_path, {"a": "first"})
    (out / "cells" / "mine").mkdir()
    (out / "cells" / "mine" / "notes.txt").write_text("mine")  # a person's folder beside the cells
    (out / "cells" / "a" / "mine.txt").write_text("mine too")  # and a file inside a cell
    (out / "cells" / "c").mkdir()
    (out / "cells" / "c" / "cell.json").write_text("{}")  # a cell a killed run finished (not listed yet)
    _grow(out, tmp_path, {"b": "second"})  # a resume: lists its new cell and the killed run's, nothing else
    with pytest.raises(
        OutputError,
        match=r"holds files msa-slam did not write \(cells/a/mine.txt, "
        r"cells/mine/notes.txt\)",
    ):
        _grow(out, tmp_path, {}, overwrite=True)
    (out / "cells" / "a" / "mine.txt").unlink()
    (out / "cells" / "mine" / "notes.txt").unlink()
    (out / "cells" / "mine").rmdir()  # even empty, it would keep an --overwrite off (test_..._empty_user_folder)
    (out / "report.md").write_text("my notes\n")
    before = tree(out)
    with pytest.raises(
        OutputError,
        match=r"holds files changed since msa-slam wrote them \(report.md\); this run "
        r"would replace them",
    ):
        _grow(out, tmp_path, {"d": "third"})  # a plain rerun would have replaced report.md
    assert tree(out) == before
    (out / "report.md").write_text("cells: ['a', 'b', 'c', 'mine']\n")
    (out / "cells" / "b" / "x.txt").write_text("edited")  # an edit inside a cell: a resume leaves it alone...
    _grow(out, tmp_path, {"d": "third"})
    with pytest.raises(OutputError, match=r"holds files changed since msa-slam wrote them \(cells/b/x.txt\)"):
        _grow(out, tmp_path, {}, overwrite=True)  # ...and does not take it for msa-slam's
    (out / "cells" / "b" / "x.txt").write_text("second")
    _grow(out, tmp_path, {}, overwrite=True)  # all msa-slam's again: replaced
    assert sorted(p.name for p in (out / "cells").iterdir()) == []


@pytest.mark.parametrize("overwrite, resume", [(True, True), (True, False), (False, False)])
def test_a_run_writing_the_folder_is_named_before_its_half_written_files(tmp_path, overwrite, resume):
    out = tmp_path / "exp"
    _grow(out, tmp_path, {"a": "first"})
    with open_result_folder(out, "experiment", tmp_path, resume=True) as folder:  # another run, growing it now
        folder.prepare_in_place(grows=("cells",), unit_record="cell.json")
        (out / "cells" / "b").mkdir()
        (out / "cells" / "b" / "x.txt").write_text("half")  # its unit, not listed yet
        (out / "report.md").write_text("being rewritten\n")  # its report, not recorded yet
        before = tree(out)
        with pytest.raises(
            OutputError,
            match=r"exp: another msa-slam run is writing this output folder; wait for "
            r"it or choose another --out",
        ):
            with open_result_folder(out, "experiment", tmp_path, overwrite=overwrite, resume=resume):
                pass
        assert tree(out) == before


def test_a_run_failing_early_leaves_no_empty_folder_it_made(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    missing = str(tmp_path / "missing")
    result = runner.invoke(app, ["run", "-d", missing, "--quiet"])  # the dataset is opened in the result's block
    assert isinstance(result.exception, InputError) and "not found" in str(result.exception)
    assert list(tmp_path.iterdir()) == []  # no msa_slam_results/run/
    (tmp_path / "msa_slam_results").mkdir()  # the user's own: stays, even empty
    result = runner.invoke(app, ["run", "-d", missing, "--quiet"])
    assert isinstance(result.exception, InputError)
    result = runner.invoke(app, ["run", "-d", missing, "--out", "a/b/out", "--quiet"])
    assert isinstance(result.exception, InputError)
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["msa_slam_results"]


def test_overwrite_never_removes_an_empty_user_folder(stream, tmp_path):
    out = tmp_path / "out"
    with open_result_folder(out, "run", tmp_path) as folder, folder.staging() as tmp:
        (tmp / "figures").mkdir()  # an empty folder msa-slam wrote: its own to replace
    with open_result_folder(out, "run", tmp_path, overwrite=True) as folder, folder.staging() as tmp:
        (tmp / "a.txt").write_text("second")
    (out / "mine" / "empty").mkdir(parents=True)
    result = sample(stream, "--out", out, "--overwrite")
    assert "holds files msa-slam did not write (mine/empty/)" in str(result.exception)
    assert (out / "mine" / "empty").is_dir() and (out / "a.txt").read_text() == "second"
    grown = tmp_path / "exp"
    _grow(grown, tmp_path, {"a": "first"})
    (grown / "cells" / "mine").mkdir()
    _grow(grown, tmp_path, {"b": "second"})  # a resume does not take it for msa-slam's
    with pytest.raises(OutputError, match=r"holds files msa-slam did not write \(cells/mine/\)"):
        _grow(grown, tmp_path, {}, overwrite=True)
    assert (grown / "cells" / "mine").is_dir()
