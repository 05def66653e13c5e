"""`msa-slam report DIR` on the folder of any command: the report.md written again from the files alone is the one
the command wrote, a folder msa-slam did not write is refused untouched, and a file someone added or edited is
never replaced. Runs without ground truth report n/a and name no ground-truth file: test_no_ground_truth.py checks
that, and `report` on their folders, on the runs it makes anyway."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from msa_slam.cli import app
from msa_slam.errors import InputError
from msa_slam.experiments.compare import run_compare
from msa_slam.io.marker import edited_files, foreign_files
from msa_slam.io.outputs import MARKER, OutputError
from msa_slam.pipeline import make_config

METHODS = (("all", "all", {}), ("constant-3m", "constant", {"distance": 3.0}))


def _cli(*args: str):
    return CliRunner().invoke(app, [*args])


def _written(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _report_again(folder: Path) -> None:
    """`msa-slam report` on `folder` writes each of its report.md files again, to the same bytes, and changes no
    other file."""
    before = _written(folder)
    for report in folder.rglob("report.md"):
        report.unlink()
    result = _cli("report", str(folder))
    assert result.exit_code == 0, result.output
    assert result.output.strip() == str(folder / "report.md")
    assert _written(folder) == before
    assert edited_files(folder) == [] and foreign_files(folder) == []


@pytest.fixture(scope="module")
def run_folder(sequence, odometry_file, cache_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("report-run") / "run"
    result = _cli(
        "run",
        "--dataset",
        str(sequence),
        "--odometry",
        str(odometry_file),
        "--sampler",
        "constant",
        "-p",
        "distance=3.0",
        "--cache-dir",
        str(cache_dir),
        "--out",
        str(out),
        "--quiet",
    )
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def compare_folder(sequence, odometry_file, cache_dir, tmp_path_factory):
    base = make_config(dataset=str(sequence), odometry=str(odometry_file), cache_dir=str(cache_dir))
    return run_compare(base, tmp_path_factory.mktemp("report-compare") / "cmp", methods=METHODS, sweep=False).parent


def test_report_of_a_run_folder_is_the_one_run_wrote(run_folder):
    _report_again(run_folder)


def test_report_of_a_compare_folder_is_the_one_compare_wrote(compare_folder):
    assert "](runs/all/report.md)" in (compare_folder / "report.md").read_text()
    _report_again(compare_folder)


def test_report_of_a_compare_seeds_folder_is_the_one_compare_wrote(tmp_path):
    base = make_config(dataset="sim:test,end=40,azimuth_steps=360", cache_dir=str(tmp_path / "cache"), odometry="kiss")
    out = run_compare(base, tmp_path / "seeds", methods=METHODS[:1], seeds=[0], sweep=False).parent
    assert (out / "seeds" / "seed-0" / "report.md").is_file()
    _report_again(out)


def test_report_refuses_a_folder_msa_slam_did_not_write(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    result = _cli("report", str(tmp_path))
    assert isinstance(result.exception, InputError)
    assert str(result.exception) == (
        f"{tmp_path}: not a msa-slam result folder (no {MARKER} written by msa-slam); "
        "expected a folder written by `msa-slam run`, `online`, `compare`, `demo`, "
        "`experiment` or `reproduce`; nothing written"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_report_names_the_result_folder_around_a_method_folder(compare_folder):
    result = _cli("report", str(compare_folder / "runs" / "all"))
    assert isinstance(result.exception, InputError)
    assert f"(it lies inside the result folder {compare_folder}: report that one)" in str(result.exception)


def test_report_never_replaces_an_edited_report_and_keeps_added_files_unlisted(run_folder, tmp_path):
    folder = tmp_path / "run"
    shutil.copytree(run_folder, folder)
    (folder / "mine.txt").write_text("notes")
    assert _cli("report", str(folder)).exit_code == 0
    assert foreign_files(folder) == ["mine.txt"]  # still not msa-slam's: an --overwrite will refuse
    (folder / "report.md").write_text("my own summary")
    result = _cli("report", str(folder))
    assert isinstance(result.exception, OutputError) and "report.md: added or edited since" in str(result.exception)
    assert (folder / "report.md").read_text() == "my own summary"


def test_report_reference_is_for_experiments_only(run_folder):
    result = _cli("report", str(run_folder), "--reference", "all")
    assert isinstance(result.exception, InputError) and "only for an experiment's folder" in str(result.exception)


def test_a_result_without_a_report_is_named(tmp_path):
    (tmp_path / MARKER).write_text(json.dumps({"tool": "msa-slam", "kind": "sample"}))
    result = _cli("report", str(tmp_path))
    assert isinstance(result.exception, InputError)
    assert "a result of `msa-slam sample`, which writes no report.md" in str(result.exception)
