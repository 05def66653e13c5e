"""Simulated sequences: configuration, an in-memory frame iterator, and cached KITTI-layout output.

A sequence directory holds velodyne/NNNNNN.bin (float32 x, y, z, intensity), poses.txt (ground truth,
LiDAR frame, KITTI 12-number lines), times.txt, calib.txt (Tr = identity, so readers that convert cam0
poses get the same) and sim.json (the config, its hash and provenance, and the sensor's elevation error, which
the KITTI-layout reader corrects: datasets.vertical_angle). With motion distortion (realism presets other than
"clean") it also holds velodyne_times/NNNNNN.npy: float32 seconds of each point from its
sweep's start (datasets.point_times). KITTI's convention: scan k's timestamp t_k (times.txt) and ground-truth
pose are those of the forward-facing column, which fires at mid-sweep; the sweep turns clockwise from the
back over [t_k - 0.05 s, t_k + 0.05 s], each column cast from the pose interpolated (trajectories.pose_at)
at its firing time, and each point is reported in the sensor frame of its own firing time (not deskewed).
For kiss-icp's KITTI loader it also holds sequences/00/ and poses/00.txt as relative links:
`KITTIOdometryDataset(DIR, "00")`.
Directories are written under a locked temporary name (`.NAME.partial-*`, marked as msa-slam's and removed
by the next run if its writer was killed) and renamed when complete, so a partial one is never mistaken for a
cached sequence; sim.json records every scan's size, so a truncated scan makes the sequence incomplete: the
next use casts the missing or truncated scans again in place (the same bytes), never replacing the folder.
Scans are independent (each frame's noise has its own seed), so a long sequence is cast by a pool of worker
processes, each holding its own copy of the world: the files are the same bytes as one process writes.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import multiprocessing
import os
import signal
from collections.abc import Iterator
from pathlib import Path

import numpy as np

import msa_slam
from msa_slam.datasets.point_times import TIMES_FOLDER
from msa_slam.datasets.vertical_angle import SIM_META
from msa_slam.errors import InputError
from msa_slam.io.atomic import write_text_atomic
from msa_slam.io.cache import cache_root, partial_dir, remove_partials
from msa_slam.io.outputs import out_path, refuse_working_directory
from msa_slam.io.poses import format_kitti
from msa_slam.io.write_errors import write_error
from msa_slam.progress import progress_bar
from msa_slam.sim.config import PARALLEL_MIN_FRAMES, SIM_VERSION, SimConfig
from msa_slam.sim.coverage import empty_scan_error, warn_short_range, warn_sparse_scans
from msa_slam.sim.simulation import Simulation, prepare

META_FILE = SIM_META  # where the KITTI-layout reader looks for the scans' elevation error
MAX_WORKERS = 4  # each worker builds and holds its own world
log = logging.getLogger(__name__)
KITTI_CITATION = "Trajectory: KITTI odometry ground truth (Geiger, Lenz, Urtasun, CVPR 2012), CC BY-NC-SA 3.0"


def _read_meta(seq_dir: Path) -> dict | None:
    try:
        return json.loads((seq_dir / META_FILE).read_text())
    except (OSError, ValueError):
        return None


def _accepted_meta(seq_dir: Path) -> dict:
    """sim.json of a simulation is_complete or _is_ours has just accepted."""
    meta = _read_meta(seq_dir)
    if meta is None:  # removed or damaged meanwhile, by another process
        raise InputError(f"{seq_dir / META_FILE}: removed or damaged while msa-slam was reading it; run again")
    return meta


def _scan_size(path: Path) -> int | None:
    try:
        return path.stat().st_size
    except OSError:
        return None


def is_complete(seq_dir: Path, key: str) -> bool:
    """True when `seq_dir` is a finished simulation of the config with this key, all scans present and of the
    size sim.json records."""
    meta = _read_meta(seq_dir)
    if meta is None or meta.get("key") != key:
        return False
    sizes, times_sizes = meta.get("scan_bytes", []), meta.get("point_times_bytes") or []
    velodyne, point_times = seq_dir / "velodyne", seq_dir / TIMES_FOLDER
    return (
        meta.get("frames") == len(sizes) == len(list(velodyne.glob("*.bin")))
        and all(_scan_size(velodyne / f"{k:06d}.bin") == size for k, size in enumerate(sizes))
        and all(_scan_size(point_times / f"{k:06d}.npy") == size for k, size in enumerate(times_sizes))
        and (seq_dir / "poses.txt").is_file()
        and (seq_dir / "times.txt").is_file()
    )


def _is_ours(seq_dir: Path, key: str) -> bool:
    """True when sim.json says `seq_dir` was simulated from this config (complete or since damaged)."""
    meta = _read_meta(seq_dir)
    return meta is not None and meta.get("key") == key


CALIB_TEXT = "".join(f"P{k}: 1 0 0 0 0 1 0 0 0 0 1 0\n" for k in range(4)) + "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n"


def _write_scan(sim: Simulation, target: Path, k: int) -> tuple[int, int | None]:
    """Cast frame k and write its scan (and per-point times); their sizes in bytes."""
    scan, point_times = sim.scan(k)
    scan.tofile(target / "velodyne" / f"{k:06d}.bin")
    if point_times is None:
        return scan.nbytes, None
    times_file = target / TIMES_FOLDER / f"{k:06d}.npy"
    np.save(times_file, point_times.astype(np.float32))
    return scan.nbytes, times_file.stat().st_size


_worker_sim: Simulation | None = None  # a pool worker's own world (_start_worker)


def _start_worker(config: SimConfig) -> None:
    """Build the worker's world. Ctrl-C is left to the parent, which ends the pool (and removes the partial
    folder) instead of every worker printing its own traceback."""
    global _worker_sim
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _worker_sim = prepare(config)


def _worker_write(job: tuple[Path, int]) -> tuple[int, int | None]:
    assert _worker_sim is not None, "pool worker used before _start_worker"
    return _write_scan(_worker_sim, *job)


def default_workers(frames: int) -> int:
    """Worker processes for a sequence of `frames` scans: one per CPU (at most MAX_WORKERS), or none (the
    calling process casts) for a short sequence, a single CPU, or a daemonic caller (a Dask worker, which may not
    start processes: its grid cells and their inputs simulate there)."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    daemon = multiprocessing.current_process().daemon
    return 0 if frames < PARALLEL_MIN_FRAMES or cpus < 2 or daemon else min(cpus, MAX_WORKERS)


def _written_scans(sim: Simulation, target: Path, workers: int, frames: list[int]) -> Iterator[tuple[int, int | None]]:
    """Each of `frames`' (scan bytes, times bytes) in order, cast here (workers 0) or by a spawned pool."""
    if workers <= 0:
        yield from (_write_scan(sim, target, k) for k in frames)
        return
    context = multiprocessing.get_context("spawn")  # not fork: the parent's ray-casting library may hold threads
    with context.Pool(workers, initializer=_start_worker, initargs=(sim.config,)) as pool:
        yield from pool.imap(_worker_write, [(target, k) for k in frames], chunksize=4)


def _cast(
    sim: Simulation, target: Path, progress: bool, workers: int, frames: list[int]
) -> tuple[list[int], list[int]]:
    """Write the scans (and per-point times) of `frames` into target/velodyne (/velodyne_times); their sizes."""
    (target / "velodyne").mkdir(parents=True, exist_ok=True)
    if not sim.realism.is_clean:
        (target / TIMES_FOLDER).mkdir(exist_ok=True)
    with progress_bar(quiet=not progress, transient=False) as bar:
        task = bar.add_task(f"simulating {sim.config.label} / {sim.config.sensor}", total=len(frames))
        sizes, times_sizes = [], []
        for k, (scan_bytes, times_bytes) in zip(frames, _written_scans(sim, target, workers, frames)):
            if scan_bytes == 0:
                raise empty_scan_error(sim.config, k, len(sim))
            sizes.append(scan_bytes)
            if times_bytes is not None:
                times_sizes.append(times_bytes)
            bar.advance(task)
    return sizes, times_sizes


def _write_layout(sim: Simulation, target: Path) -> None:
    """poses.txt, times.txt, calib.txt and the links kiss-icp's loader reads, each only where it is missing
    (a repair leaves what is there)."""
    tables = {
        "poses.txt": format_kitti(sim.poses),
        "times.txt": "".join(f"{t:.6e}\n" for t in sim.times),
        "calib.txt": CALIB_TEXT,
    }
    for name, text in tables.items():
        if not (target / name).exists():
            write_text_atomic(target / name, text)
    links = {
        Path("sequences", "00", name): Path("..", "..", name)
        for name in ("velodyne", *tables, *([] if sim.realism.is_clean else [TIMES_FOLDER]))
    }
    links[Path("poses", "00.txt")] = Path("..", "poses.txt")
    for link, points_to in links.items():
        if not (target / link).is_symlink() and not (target / link).exists():
            (target / link).parent.mkdir(parents=True, exist_ok=True)
            (target / link).symlink_to(points_to)


def _write(sim: Simulation, target: Path, progress: bool, workers: int) -> None:
    sizes, times_sizes = _cast(sim, target, progress, workers, list(range(len(sim))))
    _write_layout(sim, target)
    _write_meta(sim, target, sizes, times_sizes)
    warn_sparse_scans(sim.config, sizes)


def _write_meta(sim: Simulation, target: Path, sizes: list[int], times_sizes: list[int]) -> None:
    """sim.json, written last (atomically): it marks the sequence complete."""
    meta = {
        "key": sim.config.key(),
        "sim_version": SIM_VERSION,
        "msa_slam_version": msa_slam.__version__,
        "config": sim.config.model_dump(),
        "frames": len(sim),
        "scan_bytes": sizes,
        "point_times_bytes": times_sizes or None,
        "source_frames": sim.frames.tolist(),
        "sensor": {
            "beams": sim.lidar.model.beams,
            "azimuth_steps": sim.lidar.model.azimuth_steps,
            "max_range": sim.lidar.model.max_range,
            "elevation_bias_deg": sim.realism.sensor.elevation_bias_deg,
        },  # the reader corrects it
        "world_triangles": sim.world.triangles,
        "trajectory_files_sha256": sim.config._files_sha256,
        "source": (
            f"trajectory file {sim.config.trajectory}"
            if sim.config.is_file
            else KITTI_CITATION
            if sim.config.trajectory.startswith("kitti")
            else "procedural"
        ),
    }
    write_text_atomic(target / META_FILE, json.dumps(meta, indent=1))


def simulate_sequence(
    config: SimConfig,
    out: str | os.PathLike | None = None,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
    workers: int | None = None,
) -> Path:
    """Write (or reuse) the sequence of `config`; returns its directory.

    Without `out` the directory is <cache>/<trajectory>_<sensor>_<key>. An existing complete
    simulation of the same config is returned as is; one of the same config with a missing or truncated
    scan is repaired in place (with a warning): only those scans are cast again (the same bytes: every frame
    has its own noise seed), and files msa-slam did not write there stay. Any other existing non-empty `out`
    is an error. A scan without points is an error as soon as it is cast (nothing is written); scans too
    sparse to register, or a max_range too short for odometry, give one warning each, again whenever the
    sequence is reused (sim/coverage.py). A failed write (full disk, no permission) is one line.
    `workers`: processes casting scans (0: this one; None: `default_workers`); the bytes do not depend on it.
    """
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise InputError(f"simulate: workers must be an integer >= 0, got {workers!r}")
    key = config.key()
    target = out_path(out) if out is not None else cache_root(cache_dir) / f"{config.label}_{config.sensor}_{key}"
    remove_partials(target.parent, target.name)
    if is_complete(target, key):
        warn_short_range(config)
        warn_sparse_scans(config, _accepted_meta(target)["scan_bytes"])  # as when it was written
        return target
    if _is_ours(target, key):
        _repair(config, target, progress, workers)
        return target
    if target.exists() and (not target.is_dir() or any(target.iterdir())):
        raise InputError(
            f"{target}: exists and is not a complete simulation of this config (key {key}); "
            "remove it or choose another output directory"
        )
    if out is not None:  # the new sequence takes the folder's place (reused or repaired, it stays)
        refuse_working_directory(out)
    sim = prepare(config)
    with _writing(target):
        target.parent.mkdir(parents=True, exist_ok=True)
        with partial_dir(target.parent, target.name) as tmp, _writing(target, tmp):  # mapped before tmp goes
            _write(sim, tmp / "seq", progress, default_workers(len(sim)) if workers is None else workers)
            try:
                if target.exists():
                    target.rmdir()  # an empty directory (checked above) is replaced
                os.replace(tmp / "seq", target)
            except OSError:  # a concurrent writer may have finished first: its folder is no longer empty
                if not is_complete(target, key):
                    raise
    return target


@contextlib.contextmanager
def _writing(target: Path, written: Path | None = None) -> Iterator[None]:
    """A failed write of the sequence (staged in `written`) as one line (a full disk, no permission:
    write_errors.write_error), told while what was written is still there (its size, the space then free)."""
    try:
        yield
    except OSError as exc:
        error = write_error(
            exc, target, written, writing=True, advice="choose a writable --out or cache folder (MSA_SLAM_CACHE)"
        )
        assert error is not None, "write_error words every OSError of a write (writing=True)"
        raise error from None


def _damaged_frames(seq_dir: Path, meta: dict) -> list[int]:
    """The frames whose scan (or per-point times file) is missing or not of the size sim.json records."""
    sizes, times_sizes = meta.get("scan_bytes", []), meta.get("point_times_bytes") or []
    velodyne, point_times = seq_dir / "velodyne", seq_dir / TIMES_FOLDER
    return [
        k
        for k, size in enumerate(sizes)
        if _scan_size(velodyne / f"{k:06d}.bin") != size
        or (k < len(times_sizes) and _scan_size(point_times / f"{k:06d}.npy") != times_sizes[k])
    ]


def _repair(config: SimConfig, target: Path, progress: bool, workers: int | None) -> None:
    """Cast again, in place, the missing or truncated scans of a simulation of `config` (each into a scratch
    folder beside it, then renamed over the damaged file), write its missing tables and links, and sim.json
    last. Files msa-slam did not write there stay; scans sim.json does not list are refused (a loader would
    read them as frames)."""
    meta = _accepted_meta(target)
    listed = {f"{k:06d}.bin" for k in range(len(meta.get("scan_bytes", [])))}
    extra = sorted(p.name for p in (target / "velodyne").glob("*.bin") if p.name not in listed)
    if extra:
        raise InputError(
            f"{target}: velodyne/ holds scans {META_FILE} does not list ({', '.join(extra[:3])}); "
            "move them elsewhere (msa-slam never removes files it did not write)"
        )
    frames = _damaged_frames(target, meta)
    log.warning(
        "%s: a scan is missing or truncated (sizes differ from %s); casting %d scan(s) again in place",
        target,
        META_FILE,
        len(frames),
    )
    sim = prepare(config)
    with _writing(target), partial_dir(target.parent, target.name) as tmp, _writing(target, tmp):
        sizes, times_sizes = _cast(
            sim, tmp, progress, default_workers(len(frames)) if workers is None else workers, frames
        )
        for folder in ("velodyne", *([] if sim.realism.is_clean else [TIMES_FOLDER])):
            (target / folder).mkdir(exist_ok=True)
            for file in sorted((tmp / folder).iterdir()):
                os.replace(file, target / folder / file.name)
        _write_layout(sim, target)
        recorded, recorded_times = list(meta["scan_bytes"]), list(meta.get("point_times_bytes") or [])
        for k, size, times_size in itertools.zip_longest(frames, sizes, times_sizes):
            recorded[k] = size
            if times_size is not None:
                recorded_times[k] = times_size
        _write_meta(sim, target, recorded, recorded_times)
    warn_short_range(config)
    warn_sparse_scans(config, recorded)


# The embedded defaults (see docs in `default_sequence`).
DEFAULT_CONFIGS: dict[str, SimConfig] = {
    "demo": SimConfig(trajectory="kitti-06", sensor="hdl64", stride=1, azimuth_steps=720),
    "test": SimConfig(trajectory="figure-eight", sensor="hdl64", stride=2, azimuth_steps=360, realism="clean"),
}


def default_sequence(kind: str = "demo", cache_dir: str | os.PathLike | None = None, progress: bool = False) -> Path:
    """The embedded default sequence, simulated on first use and cached.

    "demo": the whole KITTI-06 trajectory (1.2 km, a loop driven in both directions: revisits along most of
    it) at the native 10 Hz, 1101 scans, HDL-64 beams with 720 azimuth steps (0.5 deg, ~40k points a scan),
    realism preset "kitti" (motion distortion, sensor imperfections, a changing world); docs/performance.md
    gives what `msa-slam demo` costs from an empty cache (simulation, KISS-ICP, descriptors, 7 methods).
    "test": the procedural figure-eight (revisits at its crossing and where it closes) at every 2nd
    frame, 214 scans ~2 m apart after a standing start, HDL-64 beams with 360 azimuth steps (1 deg),
    realism preset "clean" (the plain simulator the pipeline tests were written against), quick to make.
    """
    if kind not in DEFAULT_CONFIGS:
        raise InputError(f"unknown default sequence {kind!r}; choose one of {', '.join(DEFAULT_CONFIGS)}")
    return simulate_sequence(DEFAULT_CONFIGS[kind], cache_dir=cache_dir, progress=progress)
