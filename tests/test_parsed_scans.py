"""Text scans are parsed once per run (msa_slam.datasets.parsed), also by the front end's forked reader: later reads
load the run's binary copy, which gives the same arrays, and the copies go when the run lets go of its sequence."""

from __future__ import annotations

import gc
import logging
from pathlib import Path

import numpy as np
import pytest

import msa_slam.datasets.pcd as pcd
from msa_slam.datasets import SourceOptions
from msa_slam.datasets.parsed import is_text_scan
from msa_slam.descriptors import make_descriptor
from msa_slam.io.staging import WRITER, stamp
from msa_slam.pipeline.read_ahead import ReadAhead
from msa_slam.sources import open_sequence

N = 4


def _write_pcd(path: Path, k: int, mode: str) -> None:
    """Scan `k` (x y z float32 and t uint32 ns) as PCD in `mode` (ascii or binary)."""
    rng = np.random.default_rng(k)
    rows = np.empty(50, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("t", "<u4")])
    for axis in "xyz":
        rows[axis] = rng.normal(size=50) * 10
    rows["t"] = np.arange(50) * 1000
    header = (
        f"VERSION 0.7\nFIELDS x y z t\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 50\nHEIGHT 1\n"
        f"POINTS 50\nDATA {mode}\n"
    ).encode()
    body = (
        rows.tobytes() if mode == "binary" else "".join(f"{x} {y} {z} {t}\n" for x, y, z, t in rows.tolist()).encode()
    )
    path.write_bytes(header + body)


def _folder(root: Path, mode: str) -> Path:
    folder = root / f"scans-{mode}"
    folder.mkdir()
    for k in range(N):
        _write_pcd(folder / f"{k:06d}.pcd", k, mode)
    return folder


@pytest.fixture
def parses(monkeypatch) -> dict[str, int]:
    """How many times each PCD file was parsed."""
    counts: dict[str, int] = {}
    parse = pcd.read_pcd_table

    def counted(path):
        counts[Path(path).name] = counts.get(Path(path).name, 0) + 1
        return parse(path)

    monkeypatch.setattr(pcd, "read_pcd_table", counted)
    return counts


def _scratch(root: Path) -> list[Path]:
    return sorted(root.glob(".parsed-scans.run-*"))


def test_text_scans_are_told_from_binary_ones_by_their_header(tmp_path):
    _write_pcd(tmp_path / "a.pcd", 0, "ascii")
    _write_pcd(tmp_path / "b.pcd", 0, "binary")
    (tmp_path / "a.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n")
    (tmp_path / "b.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nend_header\n")
    (tmp_path / "c.bin").write_bytes(bytes(16))
    assert [is_text_scan(tmp_path / name) for name in ("a.pcd", "b.pcd", "a.ply", "b.ply", "c.bin", "none.pcd")] == [
        True,
        False,
        True,
        False,
        False,
        False,
    ]


def test_a_run_parses_each_text_scan_once_and_reads_the_same_frames(tmp_path, parses):
    folder = _folder(tmp_path, "ascii")
    plain = open_sequence(str(folder), "folder")
    expected = [plain[i] for i in range(N)]
    parses.clear()
    kept = open_sequence(str(folder), "folder", cache_dir=tmp_path / "cache", keep_parsed=True)
    for _ in range(3):  # odometry, descriptors, keyframe clouds
        for i, want in enumerate(expected):
            frame = kept[i]
            np.testing.assert_array_equal(frame.points, want.points)
            np.testing.assert_array_equal(frame.timestamps, want.timestamps)
            assert frame.points.dtype == want.points.dtype and frame.timestamps.dtype == want.timestamps.dtype
    assert parses == {f"{k:06d}.pcd": 1 for k in range(N)}
    assert len(_scratch(tmp_path / "cache")) == 1
    del kept
    gc.collect()
    assert _scratch(tmp_path / "cache") == []


def test_binary_scans_are_read_directly(tmp_path, parses):
    sequence = open_sequence(
        str(_folder(tmp_path, "binary")),
        "folder",
        cache_dir=tmp_path / "cache",
        source=SourceOptions(first=1),
        keep_parsed=True,
    )
    for _ in range(2):
        for i in range(len(sequence)):
            sequence[i]
    assert parses == {"000001.pcd": 3, "000002.pcd": 2, "000003.pcd": 2}  # the first scan selected: read by select
    assert _scratch(tmp_path / "cache") == []


def test_a_killed_runs_copies_are_removed_by_the_next_run_and_nothing_else(tmp_path):
    root = tmp_path / "cache"
    killed, foreign = root / ".parsed-scans.run-killed", root / ".parsed-scans.run-users"
    for folder in (killed, foreign):
        folder.mkdir(parents=True)
        (folder / "x-points.npy").write_bytes(b"")
    (killed / WRITER).write_bytes(stamp())  # msa-slam's mark, its lock gone with its process
    open_sequence(str(_folder(tmp_path, "binary")), "folder", cache_dir=root, keep_parsed=True)  # reads no text
    assert not killed.exists() and foreign.exists()


def test_a_cache_root_that_cannot_be_written_costs_only_the_copies(tmp_path, parses, caplog):
    (tmp_path / "cache").write_text("a file, not a folder")
    folder = _folder(tmp_path, "ascii")
    with caplog.at_level(logging.WARNING):
        sequence = open_sequence(str(folder), "folder", cache_dir=tmp_path / "cache", keep_parsed=True)
        first, again = sequence[1], sequence[1]
    np.testing.assert_array_equal(first.points, again.points)
    assert parses["000001.pcd"] == 2
    assert len([r for r in caplog.records if "cannot keep parsed scans" in r.message]) == 1  # once, not every read


def test_the_copies_a_forked_reader_makes_are_this_runs(tmp_path, monkeypatch):
    """The front end's reader is a forked process: the text scans it parses are kept where the run reads them
    again (each parsed once in all) and removed with the run's sequence."""
    log = tmp_path / "parses.log"  # appended to by whichever process parses
    parse = pcd.read_pcd_table

    def counted(path):
        with log.open("a") as out:
            out.write(f"{Path(path).name}\n")
        return parse(path)

    monkeypatch.setattr(pcd, "read_pcd_table", counted)
    folder = _folder(tmp_path, "ascii")
    _write_pcd(folder / "000000.pcd", 0, "binary")  # opening reads only the first scan: no text read before the pass
    kept = open_sequence(str(folder), "folder", cache_dir=tmp_path / "cache", keep_parsed=True)
    log.unlink()
    assert kept.forkable and _scratch(tmp_path / "cache") == []
    read = list(ReadAhead(kept, make_descriptor("sc")))
    again = [kept[i] for i in range(N)]  # the back end's reads, in this process
    for a, b in zip(read, again, strict=True):
        np.testing.assert_array_equal(a.points, b.points)
    assert sorted(log.read_text().splitlines()) == ["000000.pcd", "000000.pcd", *(f"{k:06d}.pcd" for k in range(1, N))]
    assert len(_scratch(tmp_path / "cache")) == 1
    del kept
    gc.collect()
    assert _scratch(tmp_path / "cache") == []
