"""Caches never serve stale or damaged data and never break a run (msa_slam.io.cache and its users).

The data is a 12-scan KITTI-layout copy of part of the simulated "test" sequence (conftest.py), run through
the real front end: KISS-ICP odometry and Scan Context descriptors.
"""

from __future__ import annotations

import errno
import logging
import os
import shutil
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

import numpy as np
from helpers.cache_data import data, fill_excerpt  # noqa: F401 (data: a fixture)

import msa_slam.io.cache
import msa_slam.odometry.cache
from msa_slam.datasets import open_dataset
from msa_slam.io.cache import CacheDir, locked_temp
from msa_slam.odometry import KissOdometry, OdometryCache
from msa_slam.pipeline import make_config, prepare_frontend
from msa_slam.pipeline.config import make_online_config
from msa_slam.pipeline.live import make_online_odometry
from msa_slam.sources import open_source


def _config(data: Path, cache: Path, **fields):
    return make_config(dataset=str(data), cache_dir=str(cache), **fields)


def test_scans_replaced_in_place_are_recomputed(sequence, data, tmp_path):
    cfg = _config(data, tmp_path / "cache")
    first = prepare_frontend(cfg)
    assert first.cached == {"odometry": False, "descriptors": False, "clouds": False}
    fill_excerpt(data, sequence, 100)  # same path, same number of scans, other data
    again = prepare_frontend(cfg)
    assert again.cached == {"odometry": False, "descriptors": False, "clouds": False}
    assert np.abs(again.odometry[-1, :3, 3] - first.odometry[-1, :3, 3]).max() > 1.0
    fresh = prepare_frontend(_config(data, tmp_path / "fresh"))
    np.testing.assert_allclose(again.odometry, fresh.odometry, atol=1e-6)
    np.testing.assert_array_equal(again.descriptors, fresh.descriptors)


def test_same_data_elsewhere_is_a_hit_and_settings_are_part_of_the_key(data, tmp_path):
    cache = tmp_path / "cache"
    first = prepare_frontend(_config(data, cache))
    copy = Path(shutil.copytree(data, tmp_path / "elsewhere" / "copy"))  # copy2 keeps sizes and mtimes
    moved = prepare_frontend(_config(copy, cache))
    assert moved.cached == {"odometry": True, "descriptors": True, "clouds": True}
    np.testing.assert_array_equal(moved.odometry, first.odometry)
    np.testing.assert_array_equal(moved.descriptors, first.descriptors)
    other = prepare_frontend(_config(copy, cache, descriptor_params={"n_sector": 30}))
    assert other.cached == {"odometry": True, "descriptors": False, "clouds": True}
    other = prepare_frontend(_config(copy, cache, odometry_params={"max_range": 60.0}))
    assert other.cached == {"odometry": False, "descriptors": True, "clouds": True}


def test_odometry_key_covers_threads_versions_and_code(data, monkeypatch):
    seq = open_dataset(data)
    config = KissOdometry().config
    key = OdometryCache.key(seq, config)
    threads = {**config, "registration": {**config["registration"], "max_num_threads": 7}}
    assert OdometryCache.key(seq, threads) != key
    real_version = metadata.version
    monkeypatch.setattr(metadata, "version", lambda name: "0.0.1" if name == "kiss-icp" else real_version(name))
    assert OdometryCache.key(seq, config) != key
    monkeypatch.undo()
    monkeypatch.setattr(msa_slam.odometry.cache, "code_fingerprint", lambda modules: "other code")
    assert OdometryCache.key(seq, config) != key


def test_odometry_key_covers_the_frame_times(data):
    seq = open_dataset(data)
    config = KissOdometry().config
    key = OdometryCache.key(seq, config)
    seq.times = seq.times * 2.0  # the same scans with other times (an edited times.txt): deskewing differs
    assert OdometryCache.key(seq, config) != key


def test_online_replays_the_odometry_of_the_scans_it_reads(data, tmp_path, caplog):
    """Each selection of scans (-n) has its own odometry entry, and online finds the one of the scans it reads:
    keyed as the whole recording, online -n 6 found the 12 rows of a full run and warned as if it were damaged."""
    cache = tmp_path / "cache"
    runs = {
        frames: prepare_frontend(_config(data, cache, sampler="all", source={"frames": frames})) for frames in (None, 6)
    }
    assert not any(run.cached["odometry"] for run in runs.values())
    assert len(list((cache / "pipeline").glob("odometry-*.npy"))) == 2
    for frames, run in runs.items():
        config = make_online_config(dataset=str(data), cache_dir=str(cache), source={"frames": frames})
        source = open_source(config.dataset, source=config.source)
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            odometry, cached = make_online_odometry(config, source, len(source))
        assert cached and [r.getMessage() for r in caplog.records] == []
        replayed = np.stack([odometry.register() for _ in range(len(source))])
        np.testing.assert_array_equal(replayed, run.odometry)


def test_run_and_online_from_the_cache_name_the_frames_kiss_icp_could_not_register(tmp_path):
    """A cached front end (run) and a replayed one (online) say which frames were only extrapolated, as a fresh
    run does: frame 5 lies beyond max_range."""
    rng = np.random.default_rng(1)
    near = np.hstack([rng.normal(size=(3000, 3)) * 10.0, np.zeros((3000, 1))]).astype(np.float32)
    data = tmp_path / "seq"
    data.mkdir()
    for k in range(12):
        (near + np.float32(500.0) if k == 5 else near).tofile(data / f"{k:06d}.bin")
    line = (
        "odometry: KISS-ICP could not register 1 of 12 frames (frame 5): fewer than 3 of their points lie "
        "within 0-50 m, so their poses were extrapolated at constant velocity"
    )
    cfg = _config(data, tmp_path / "cache", sampler="all", mode="realistic", odometry_params={"max_range": 50.0})
    fresh, cached = prepare_frontend(cfg), prepare_frontend(cfg)
    assert not fresh.cached["odometry"] and cached.cached["odometry"]
    assert line in fresh.warnings and line in cached.warnings
    config = make_online_config(
        dataset=str(data), cache_dir=str(tmp_path / "cache"), mode="realistic", odometry_params={"max_range": 50.0}
    )
    odometry, replayed = make_online_odometry(config, open_source(config.dataset, mode="realistic"), 12)
    assert replayed and odometry.notes == [line]


def test_truncated_or_nan_entries_are_recomputed_with_a_warning(data, tmp_path, caplog):
    cfg = _config(data, tmp_path / "cache")
    first = prepare_frontend(cfg)
    files = sorted((tmp_path / "cache" / "pipeline").glob("*.npy"))
    # each entry's per-frame compute times (ms-NAME), the odometry's unregistered frames beside the entries, the
    # frame clouds' points and offsets
    assert sorted(p.name.split("-")[0] for p in files) == [
        "descriptors",
        "frame",
        "frame",
        "ms",
        "ms",
        "ms",
        "odometry",
        "unregistered",
    ]
    entries = {p.name.split("-")[0]: p for p in files if not p.name.startswith("ms-")}
    odometry = entries["odometry"]
    odometry.write_bytes(odometry.read_bytes()[:300])
    poisoned = np.load(entries["descriptors"])
    poisoned[3] = np.nan
    np.save(entries["descriptors"], poisoned)
    with caplog.at_level(logging.WARNING):
        again = prepare_frontend(cfg)
    assert again.cached == {"odometry": False, "descriptors": False, "clouds": True}
    assert f"ignoring {odometry}" in caplog.text
    assert f"ignoring {entries['descriptors']} (NaN or infinite values)" in caplog.text
    np.testing.assert_allclose(again.odometry, first.odometry, atol=1e-6)
    np.testing.assert_array_equal(again.descriptors, first.descriptors)
    assert prepare_frontend(cfg).cached == {"odometry": True, "descriptors": True, "clouds": True}  # rewritten
    times = tmp_path / "cache" / "pipeline" / f"ms-{entries['descriptors'].stem}.npy"
    np.save(times, -np.load(times) - 1.0)  # negative: not what computing took, so the entry is not replayed
    with caplog.at_level(logging.WARNING):
        assert prepare_frontend(cfg).cached == {"odometry": True, "descriptors": False, "clouds": True}
    assert f"ignoring {times} (negative times)" in caplog.text


def test_rotated_poses_entry_is_not_trusted(tmp_path, caplog):
    cache = OdometryCache(tmp_path)
    poses = np.tile(np.eye(4), (3, 1, 1))
    cache.save("k", poses, [], np.zeros(3))
    skewed = poses.copy()
    skewed[1, :3, :3] *= 2.0
    np.save(cache.path("k"), skewed)
    assert cache.load("k", 3) is None and "not a rigid transform" in caplog.text
    np.save(cache.path("k"), poses)
    assert cache.load("k", 4) is None and "shape (3, 4, 4), expected (4, 4, 4)" in caplog.text


def test_unwritable_cache_only_costs_the_cache(data, tmp_path, caplog):
    root = tmp_path / "cache"
    root.mkdir()
    if os.geteuid() == 0:  # root ignores permissions: a file where the folder should be fails the same way
        (root / "pipeline").write_text("not a folder")
    else:
        root.chmod(0o500)
    try:
        with caplog.at_level(logging.WARNING):
            frontend = prepare_frontend(_config(data, root))
    finally:
        root.chmod(0o700)
    warnings = [r.getMessage() for r in caplog.records if "cannot write" in r.getMessage()]
    assert len(warnings) == 1 and str(root / "pipeline") in warnings[0] and "without the cache" in warnings[0]
    assert frontend.cached == {"odometry": False, "descriptors": False, "clouds": False}
    reference = prepare_frontend(_config(data, tmp_path / "ok"))
    np.testing.assert_allclose(frontend.odometry, reference.odometry, atol=1e-6)


def test_full_disk_warns_once_and_leaves_no_temp(tmp_path, monkeypatch, caplog):
    def no_space(handle, array):
        handle.write(b"partial")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    store = CacheDir(tmp_path)
    monkeypatch.setattr(np, "save", no_space)
    assert store.save("a", np.zeros(10)) is None and store.save("b", np.zeros(10)) is None
    assert [r.getMessage() for r in caplog.records] == [
        f"cache: cannot write {tmp_path / 'a.npy'} (No space left on device; needs 0.00 MiB); "
        "continuing without the cache"
    ]
    assert list(tmp_path.iterdir()) == []


def test_entries_respect_the_umask(tmp_path):
    old = os.umask(0o027)
    try:
        path = CacheDir(tmp_path / "c").save("a", np.zeros(3))
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o640 and path.parent.stat().st_mode & 0o777 == 0o750


def test_temporaries_of_killed_writers_are_removed(tmp_path, monkeypatch):
    code = (
        "import os, sys; from pathlib import Path; from msa_slam.io.cache import locked_temp\n"
        "with locked_temp(Path(sys.argv[1])) as handle:\n"
        "    handle.write(b'half an entry'); handle.flush(); os._exit(9)\n"
    )
    killed = subprocess.run([sys.executable, "-c", code, str(tmp_path / "odometry-k.npy")])
    assert killed.returncode == 9
    (orphan,) = tmp_path.glob(".*.tmp")
    user_file = tmp_path / "notes.tmp"
    user_file.write_text("not ours: no leading dot")
    with locked_temp(tmp_path / "descriptors-k.npy"):  # a writer still at work
        (live,) = tmp_path.glob(".descriptors-k.npy.*.tmp")
        monkeypatch.setattr(msa_slam.io.cache, "RUN_START_NS", time.time_ns())  # a later run starts
        young = tmp_path / ".young.npy.x.tmp"  # unlocked but newer than this run: maybe a writer just starting
        young.write_bytes(b"")
        os.utime(young, ns=(msa_slam.io.cache.RUN_START_NS + 10**9,) * 2)
        CacheDir(tmp_path)
        assert not orphan.exists()
        assert live.exists() and young.exists() and user_file.exists()
