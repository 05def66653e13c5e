"""Caches and resumed experiment cells are keyed by what made them: the content of the inputs and the code.

Faults injected: an edited copy of msa-slam's sources (never the real ones), a dataset copied and edited with
its modification times restored, a scan edited in place likewise, a moved folder, a damaged digest memo,
changed scans under a finished experiment cell, and cache entries of the wrong shape, precision or byte order.
The data is the 12-scan KITTI-layout excerpt of the simulated "test" sequence that tests/test_cache.py makes.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers.cache_data import data, fill_excerpt  # noqa: F401 (data: a fixture)

import msa_slam.io.cache
import msa_slam.io.fingerprint
from msa_slam.datasets import open_dataset
from msa_slam.descriptors.cache import DESCRIPTOR_CODE, descriptor_key
from msa_slam.errors import InputError
from msa_slam.experiments import expand, parse_grid, run_grid
from msa_slam.io.cache import DIGESTS_FILE, CacheDir, input_identity
from msa_slam.io.fingerprint import PACKAGE_DIR, code_fingerprint, import_closure
from msa_slam.io.outputs import OutputError
from msa_slam.odometry import KissOdometry, OdometryCache
from msa_slam.pipeline import make_config, prepare_frontend
from msa_slam.sim import DEFAULT_CONFIGS


def _frontend(data: Path, cache: Path, **fields):
    return prepare_frontend(make_config(dataset=str(data), cache_dir=str(cache), **fields))


def _package_copy(where: Path) -> Path:
    """A copy of msa_slam's sources, to edit instead of the real ones."""
    return Path(shutil.copytree(PACKAGE_DIR, where / "msa_slam", ignore=shutil.ignore_patterns("__pycache__")))


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def _shift_keeping_times(scan: Path, dx: float) -> None:
    """Move the scan's points by `dx` m (same size) and restore its access and modification times to the ns."""
    st = scan.stat()
    points = np.fromfile(scan, dtype=np.float32).reshape(-1, 4)
    points[:, 0] += np.float32(dx)
    points.tofile(scan)
    os.utime(scan, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert scan.stat().st_size == st.st_size and scan.stat().st_mtime_ns == st.st_mtime_ns


def test_a_source_edit_changes_the_keys_of_what_that_code_computes_only(data, tmp_path, monkeypatch):
    seq = open_dataset(data)
    config = KissOdometry().config
    keys = {
        "descriptors": descriptor_key(seq, "sc", {}),
        "odometry": OdometryCache.key(seq, config),
        "simulation": DEFAULT_CONFIGS["test"].key(),
    }

    def keys_with(package: Path) -> dict[str, str]:
        monkeypatch.setattr(msa_slam.io.fingerprint, "PACKAGE_DIR", package)
        return {
            "descriptors": descriptor_key(seq, "sc", {}),
            "odometry": OdometryCache.key(seq, config),
            "simulation": DEFAULT_CONFIGS["test"].key(),
        }

    assert keys_with(_package_copy(tmp_path / "same")) == keys  # where the package is installed does not count
    edited = _package_copy(tmp_path / "descriptors")
    _edit(
        edited / "descriptors" / "scan_context.py",
        "self.shape = (self.n_ring, self.n_sector)",
        "self.shape = (self.n_ring, self.n_sector)  # an edit",
    )
    changed = keys_with(edited)
    assert changed["descriptors"] != keys["descriptors"]
    assert (changed["odometry"], changed["simulation"]) == (keys["odometry"], keys["simulation"])
    simulator = _package_copy(tmp_path / "sim")
    _edit(simulator / "sim" / "scan.py", "\n", "\n# an edit\n")
    changed = keys_with(simulator)
    assert changed["simulation"] != keys["simulation"] and changed["descriptors"] == keys["descriptors"]


def test_the_import_closure_follows_imports_inside_functions(tmp_path):
    """Sources are read once per process, so each state of the code is its own copy."""
    assert "msa_slam.backend.graph" not in import_closure(DESCRIPTOR_CODE, _package_copy(tmp_path / "before"))
    package = _package_copy(tmp_path / "after")
    base = package / "descriptors" / "base.py"
    base.write_text(base.read_text() + "\n\ndef _late():\n    from msa_slam.backend import graph\n")
    assert "msa_slam.backend.graph" in import_closure(DESCRIPTOR_CODE, package)
    assert code_fingerprint(DESCRIPTOR_CODE, package_dir=package) != code_fingerprint(DESCRIPTOR_CODE)


def test_edited_data_with_restored_times_is_recomputed_and_a_moved_folder_is_a_hit(data, tmp_path):
    cache = tmp_path / "cache"
    original = _frontend(data, cache)
    copy = Path(shutil.copytree(data, tmp_path / "data-m"))  # cp -a: same sizes and mtimes
    for k in range(6, 12):
        _shift_keeping_times(copy / "velodyne" / f"{k:06d}.bin", 1.5)
    edited = _frontend(copy, cache)
    assert edited.cached == {"odometry": False, "descriptors": False, "clouds": False}
    fresh = _frontend(copy, tmp_path / "fresh")
    np.testing.assert_array_equal(edited.odometry, fresh.odometry)
    np.testing.assert_array_equal(edited.descriptors, fresh.descriptors)
    assert not np.array_equal(edited.descriptors, original.descriptors)

    _shift_keeping_times(data / "velodyne" / "000003.bin", 1.5)  # in place
    assert _frontend(data, cache).cached == {"odometry": False, "descriptors": False, "clouds": False}

    moved = tmp_path / "elsewhere" / "data-m"
    moved.parent.mkdir()
    copy.rename(moved)
    again = _frontend(moved, cache)
    assert again.cached == {"odometry": True, "descriptors": True, "clouds": True}
    np.testing.assert_array_equal(again.odometry, edited.odometry)


def test_a_warm_run_reads_no_input_again_and_a_damaged_memo_is_rebuilt(data, tmp_path, monkeypatch, caplog):
    reads: list[str] = []
    real = msa_slam.io.cache.file_sha256

    def counted(path):
        reads.append(os.fspath(path))
        return real(path)

    monkeypatch.setattr(msa_slam.io.cache, "file_sha256", counted)
    cache = tmp_path / "cache"
    _frontend(data, cache)
    scans = sorted(str(p) for p in (data / "velodyne").iterdir())
    assert sorted(reads) == scans  # each scan read once, for the odometry's and the descriptors' keys
    reads.clear()
    assert _frontend(data, cache).cached == {"odometry": True, "descriptors": True, "clouds": True}
    assert reads == []  # the memo on disk, read by a new CacheDir, spares every scan
    index = cache / "pipeline" / DIGESTS_FILE
    index.write_text('{"/x": "not an entry"}')
    with caplog.at_level(logging.WARNING):
        assert _frontend(data, cache).cached == {"odometry": True, "descriptors": True, "clouds": True}
    assert sorted(reads) == scans
    assert _cache_warnings(caplog) == [f"cache: ignoring {index} (not an index of file digests); rebuilding it"]
    assert sorted(json.loads(index.read_text())) == scans


def _cache_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "msa_slam.io.cache"]


def _two_dataset_grid(first: Path, second: Path, cache: Path) -> dict:
    return {
        "name": "identity",
        "pipeline": "batch",
        "datasets": [str(first), str(second)],
        "samplers": ["all"],
        "base": {"cache_dir": str(cache), "odometry_params": {"voxel_size": 1.5}},
    }


def test_a_resumed_grid_reruns_only_the_cells_whose_data_changed(sequence, tmp_path, caplog):
    first, second = fill_excerpt(tmp_path / "a", sequence, 0), fill_excerpt(tmp_path / "b", sequence, 40)
    grid = parse_grid(_two_dataset_grid(first, second, tmp_path / "cache"))
    on_first, on_second = expand(grid)
    out = tmp_path / "out"
    assert sorted(run_grid(grid, out).ran) == sorted([on_first.id, on_second.id])
    before = json.loads((out / "cells" / on_first.id / "metrics.json").read_text())
    for k in range(8, 12):
        _shift_keeping_times(first / "velodyne" / f"{k:06d}.bin", 3.0)
    with caplog.at_level(logging.WARNING):
        run = run_grid(grid, out)
    line = f"cell {on_first.id}: its data changed since it ran; rerun"
    assert run.rerun == {on_first.id: line} and run.ran == [on_first.id] and run.skipped == [on_second.id]
    assert f"experiment: {line}" in caplog.text and f"- {line}" in (out / "report.md").read_text()
    after = json.loads((out / "cells" / on_first.id / "metrics.json").read_text())
    assert after["before"] != before["before"]  # the new data's odometry, not the old cell's
    assert run_grid(grid, out).skipped == [on_first.id, on_second.id]  # recorded anew: a third run reuses both


def test_a_cell_to_rerun_holding_a_persons_file_is_refused_and_kept(sequence, tmp_path):
    first, second = fill_excerpt(tmp_path / "a", sequence, 0), fill_excerpt(tmp_path / "b", sequence, 40)
    grid = parse_grid(_two_dataset_grid(first, second, tmp_path / "cache"))
    on_first, _ = expand(grid)
    out = tmp_path / "out"
    run_grid(grid, out)
    notes = out / "cells" / on_first.id / "notes.txt"
    notes.write_text("mine\n")
    for k in range(8, 12):
        _shift_keeping_times(first / "velodyne" / f"{k:06d}.bin", 3.0)
    with pytest.raises(
        OutputError,
        match=rf"cell {on_first.id} must be rerun, but its folder holds files msa-slam "
        rf"did not write \(cells/{on_first.id}/notes.txt\)",
    ):
        run_grid(grid, out)
    assert notes.read_text() == "mine\n" and (out / "cells" / on_first.id / "cell.json").is_file()
    notes.unlink()
    assert run_grid(grid, out).ran == [on_first.id]  # without the person's file, the cell is rerun


@pytest.mark.parametrize(
    "kind, damage, reason",
    [
        (
            "descriptors",
            lambda a: a.reshape(len(a), a.shape[2], a.shape[1]),
            "shape (12, 60, 20), expected (12, 20, 60)",
        ),
        ("descriptors", lambda a: a.astype(np.float32), "dtype <f4, expected <f8"),
        ("descriptors", lambda a: a.astype(">f8"), "dtype >f8, expected <f8"),
        ("odometry", lambda a: a.astype(np.float32), "dtype <f4, expected <f8"),
        ("odometry", lambda a: a.astype(">f8"), "dtype >f8, expected <f8"),
        ("odometry", lambda a: a[:, :3, :], "shape (12, 3, 4), expected (12, 4, 4)"),
    ],
)
def test_entries_of_another_shape_precision_or_byte_order_are_recomputed(data, tmp_path, caplog, kind, damage, reason):
    cache = tmp_path / "cache"
    first = _frontend(data, cache)
    (entry,) = (cache / "pipeline").glob(f"{kind}-*.npy")
    np.save(entry, damage(np.load(entry)))
    with caplog.at_level(logging.WARNING):
        again = _frontend(data, cache)
    assert again.cached == {"odometry": kind != "odometry", "descriptors": kind != "descriptors", "clouds": True}
    warnings = _cache_warnings(caplog)
    assert len(warnings) == 1 and warnings[0].startswith(f"cache: ignoring {entry} ({reason}")
    np.testing.assert_array_equal(again.odometry, first.odometry)
    np.testing.assert_array_equal(again.descriptors, first.descriptors)
    assert np.load(entry).dtype == np.dtype("<f8")  # rewritten


def test_inputs_hashed_on_several_threads_keep_their_order_and_memo(tmp_path):
    """input_identity hashes the files on several threads: the identity lists them in the order given with the
    digests of their bytes, the memo holds every one, and the first unreadable file in that order is named."""
    folder = tmp_path / "scans"
    folder.mkdir()
    files = [folder / f"{i:03d}.bin" for i in range(40)]
    for i, file in enumerate(files):
        file.write_bytes(np.random.default_rng(i).bytes(50_000 + i))
    cache = CacheDir(tmp_path / "cache")
    identity = input_identity(reversed(files), folder, cache)
    assert identity == [[f.name, hashlib.sha256(f.read_bytes()).hexdigest()] for f in reversed(files)]
    memo = json.loads((tmp_path / "cache" / DIGESTS_FILE).read_text())
    assert {name: entry[-1] for name, entry in memo.items()} == {str(f): d for f, (_, d) in zip(files[::-1], identity)}
    unreadable = [*files[:5], folder / "gone-1.bin", *files[5:], folder / "gone-2.bin"]
    with pytest.raises(InputError, match=f"^{folder / 'gone-1.bin'}: cannot read this input file"):
        input_identity(unreadable, folder)
