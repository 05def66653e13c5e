"""The wheel ships everything the package reads at run time: the grid presets and the data folder."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "src" / "msa_slam"


def _shipped_files() -> list[str]:
    """Package-relative paths (as in the wheel) of the non-Python files msa-slam opens at run time."""
    files = sorted((PACKAGE / "experiments" / "grids").glob("*.yaml"))
    files += sorted(p for p in (PACKAGE / "data").rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    return [p.relative_to(PACKAGE.parent).as_posix() for p in files]


def test_wheel_contains_grid_presets_and_data(tmp_path):
    pytest.importorskip("setuptools")
    pytest.importorskip("wheel")
    source = tmp_path / "src-copy"  # build a copy: an in-tree build would leave build/ in the working tree
    shutil.copytree(REPO / "src", source / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, source / name)
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "--no-index",
            "-q",
            "-w",
            str(tmp_path / "dist"),
            str(source),
        ],
        check=True,
        capture_output=True,
        timeout=120,
    )
    (wheel,) = (tmp_path / "dist").glob("msa_slam-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = _shipped_files()
    assert "msa_slam/experiments/grids/tiny.yaml" in expected and "msa_slam/data/trajectories/kitti_05.npz" in expected
    assert [n for n in expected if n not in names] == []
