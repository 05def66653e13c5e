"""Simulated sequences: configuration, an in-memory frame iterator, and cached KITTI-layout output.

A sequence directory holds velodyne/NNNNNN.bin (float32 x, y, z, intensity), poses.txt (ground truth,
LiDAR frame, KITTI 12-number lines), times.txt, calib.txt (Tr = identity, so readers that convert cam0
poses get the same) and sim.json (the config, its hash and provenance). With motion distortion (realism
presets other than "clean") it also holds velodyne_times/NNNNNN.npy: float32 seconds of each point from its
sweep's start (datasets.point_times). KITTI's convention: scan k's timestamp t_k (times.txt) and ground-truth
pose are those of the forward-facing column, which fires at mid-sweep; the sweep turns clockwise from the
back over [t_k - 0.05 s, t_k + 0.05 s], each column cast from the pose interpolated (trajectories.pose_at)
at its firing time, and each point is reported in the sensor frame of its own firing time (not deskewed). For kiss-icp's KITTI loader it
also holds sequences/00/ and poses/00.txt as relative links: `KITTIOdometryDataset(DIR, "00")`.
Directories are written under a locked temporary name (`.NAME.partial-*`, removed by the next run if
its writer was killed) and renamed when complete, so a partial one is never mistaken for a cached sequence;
sim.json records every scan's size, so a truncated scan makes the sequence incomplete (simulated again).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Iterator, NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, PrivateAttr, ValidationError, field_validator, model_validator

import msa_slam
from msa_slam.errors import InputError
from msa_slam.io.cache import cache_key, partial_dir, remove_orphans
from msa_slam.io.poses import POSE_FORMATS, format_kitti
from msa_slam.datasets.point_times import TIMES_FOLDER
from msa_slam.sim.layout import STYLES
from msa_slam.sim.realism import DEFAULT_REALISM, REALISM, Realism
from msa_slam.sim.sensors import SENSORS, Lidar, LidarModel, get_sensor
from msa_slam.sim.trajectories import TRAJECTORY_NAMES, Trajectory, frame_indices, load_trajectory, read_trajectory
from msa_slam.sim.world import World, build_world

SIM_VERSION = "3"  # bump when generated worlds or scans change, so stale caches are not reused
SIM_LIBRARIES = ("trimesh", "embreex", "numpy")  # ray casting and noise: part of the cache key
META_FILE = "sim.json"
log = logging.getLogger(__name__)
KITTI_CITATION = ("Trajectory: KITTI odometry ground truth (Geiger, Lenz, Urtasun, CVPR 2012), "
                  "CC BY-NC-SA 3.0")


class SimConfig(BaseModel):
    """Everything that determines a simulated sequence (and so its cache key)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    trajectory: str = "kitti-05"  # a shipped name, or a pose file (KITTI or TUM format)
    trajectory_format: str = "auto"  # of a trajectory file: auto, kitti or tum
    times: str | None = None  # of a KITTI-format trajectory file: one time a line (default 10 Hz)
    calib: str | None = None  # a KITTI calib.txt whose Tr line converts cam0 poses to the LiDAR frame
    sensor: str = "hdl64"
    start: int = 0
    end: int | None = None
    stride: int = 1
    seed: int = 0
    azimuth_steps: int | None = None
    max_range: float | None = None
    range_noise: float = 0.02
    dropout: float = 0.0
    style: str | None = None  # None: "city" for vehicles, "campus" for walking platforms
    realism: str = DEFAULT_REALISM  # a preset of sim.realism: "kitti" (calibrated) or "clean"
    _files_sha256: str | None = PrivateAttr(default=None)  # content of the trajectory files: the cache key

    @field_validator("trajectory")
    @classmethod
    def _known_trajectory(cls, v: str) -> str:
        if v in TRAJECTORY_NAMES:
            return v
        path = Path(v).expanduser()
        if not path.is_file():
            raise ValueError(f"unknown trajectory {v!r}; choose one of {', '.join(TRAJECTORY_NAMES)} "
                             "or give a pose file (KITTI or TUM format)")
        return str(path.resolve())

    @field_validator("times", "calib")
    @classmethod
    def _existing_file(cls, v: str | None) -> str | None:
        if v is None:
            return v
        path = Path(v).expanduser()
        if not path.is_file():
            raise ValueError(f"{v}: file not found")
        return str(path.resolve())

    @field_validator("trajectory_format")
    @classmethod
    def _known_format(cls, v: str) -> str:
        if v not in POSE_FORMATS:
            raise ValueError(f"unknown trajectory format {v!r}; choose one of {', '.join(POSE_FORMATS)}")
        return v

    @model_validator(mode="after")
    def _read_trajectory_file(self) -> "SimConfig":
        """Check a trajectory file whole now (errors name its line, before any long work) and hash the files."""
        if self.trajectory in TRAJECTORY_NAMES:
            if self.times is not None or self.calib is not None or self.trajectory_format != "auto":
                raise ValueError(f"times, calib and trajectory_format apply to a trajectory file, not to the "
                                 f"shipped trajectory {self.trajectory!r}")
            return self
        self.load_trajectory()
        parts = [f"{what}:{hashlib.sha256(Path(f).read_bytes()).hexdigest() if f else '-'}"
                 for what, f in (("poses", self.trajectory), ("times", self.times), ("calib", self.calib))]
        self._files_sha256 = ",".join(parts)
        return self

    @property
    def is_file(self) -> bool:
        """True when the trajectory comes from a pose file rather than a shipped name."""
        return self.trajectory not in TRAJECTORY_NAMES

    @property
    def label(self) -> str:
        """A short name for folders and progress: the shipped name or the pose file's stem."""
        return f"file-{Path(self.trajectory).stem}" if self.is_file else self.trajectory

    def load_trajectory(self) -> Trajectory:
        """The whole source trajectory (shipped, or read from the files)."""
        if not self.is_file:
            return load_trajectory(self.trajectory)
        return read_trajectory(self.trajectory, self.trajectory_format, self.times, self.calib)

    @field_validator("sensor")
    @classmethod
    def _known_sensor(cls, v: str) -> str:
        if v not in SENSORS:
            raise ValueError(f"unknown sensor {v!r}; choose one of {', '.join(SENSORS)}")
        return v

    @field_validator("realism")
    @classmethod
    def _known_realism(cls, v: str) -> str:
        if v not in REALISM:
            raise ValueError(f"unknown realism preset {v!r}; choose one of {', '.join(REALISM)}")
        return v

    @field_validator("style")
    @classmethod
    def _known_style(cls, v: str | None) -> str | None:
        if v is not None and v not in STYLES:
            raise ValueError(f"unknown world style {v!r}; choose one of {', '.join(STYLES)}")
        return v

    def key(self) -> str:
        """The cache key: hash of the config (a trajectory file by its content), the realism preset's parameters,
        the simulator version and the versions of msa-slam and of the libraries that ray-cast the scans."""
        config = self.model_dump()
        if self.is_file:  # the files' content, not where they are
            config.update(trajectory="file", times=None, calib=None, trajectory_files=self._files_sha256)
        preset = asdict(REALISM[self.realism])  # its parameters: retuning a preset is a new simulation
        return cache_key("simulation", [], {"config": config, "realism_preset": preset, "sim_version": SIM_VERSION},
                         SIM_LIBRARIES)


def make_config(**fields: object) -> SimConfig:
    """A SimConfig, with validation problems reported as one InputError naming the parameters."""
    try:
        return SimConfig(**fields)
    except ValidationError as exc:
        problems = "; ".join(": ".join([*(['.'.join(map(str, e['loc']))] if e['loc'] else []),
                                         e['msg'].removeprefix('Value error, ')]) for e in exc.errors())
        raise InputError(f"simulation config: {problems}") from None


class SimFrame(NamedTuple):
    """One simulated scan: output index, time (s from the first frame), points, ground-truth pose."""

    index: int
    time: float
    points: np.ndarray
    gt_pose: np.ndarray


@dataclass
class Simulation:
    """A resolved config: the selected frames, the full-rate trajectory they come from, the world built
    around them and the bound sensor."""

    config: SimConfig
    frames: np.ndarray  # source-trajectory indices of the output frames
    trajectory: Trajectory  # full rate: motion distortion interpolates between its poses
    world: World
    lidar: Lidar
    realism: Realism

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def poses(self) -> np.ndarray:
        return self.trajectory.poses[self.frames]

    @property
    def times(self) -> np.ndarray:
        """Output frame times, seconds from the first output frame."""
        return self.trajectory.times[self.frames] - self.trajectory.times[self.frames[0]]

    def scan(self, k: int, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """(P, 4) float32 scan of output frame k and its per-point times (float64 s from the sweep start;
        None for a clean preset, whose sensor stands still); noise is seeded by (seed, source frame) unless
        `rng` is given (a live source drawing each lap's noise apart)."""
        frame = int(self.frames[k])
        rng = np.random.default_rng([self.config.seed, frame]) if rng is None else rng
        if self.realism.is_clean:
            return self.lidar.scan(self.trajectory.poses[frame], rng), None
        return self.lidar.sweep(self.trajectory.pose_at, float(self.trajectory.times[frame]), rng)


def prepare(config: SimConfig) -> Simulation:
    """Load the trajectory, select frames and build the world around the whole selected range (unstrided,
    so every stride of the same range sees the same world)."""
    traj = config.load_trajectory()
    frames = frame_indices(len(traj), config.start, config.end, config.stride, config.label)
    span = traj.poses[frames[0]:frames[-1] + 1]
    style = config.style or ("campus" if traj.platform == "walk" else "city")
    realism = REALISM[config.realism]
    world = build_world(span, style, config.seed, traj.sensor_height, realism.world)
    model: LidarModel = get_sensor(config.sensor, azimuth_steps=config.azimuth_steps, max_range=config.max_range,
                                   range_noise=config.range_noise, dropout=config.dropout)
    return Simulation(config, frames, traj, world, Lidar(model, world, realism.sensor, config.seed), realism)


def iter_frames(config: SimConfig, with_intensity: bool = False) -> Iterator[SimFrame]:
    """Simulate in memory: yields SimFrame(index, time, points (P,3) or (P,4) float32, gt_pose)."""
    sim = prepare(config)
    for k in range(len(sim)):
        pts, _ = sim.scan(k)
        yield SimFrame(k, float(sim.times[k]), pts if with_intensity else pts[:, :3].copy(), sim.poses[k])


def cache_root(cache_dir: str | os.PathLike | None = None) -> Path:
    """`cache_dir`, else $MSA_SLAM_CACHE, else ~/.cache/msa-slam."""
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("MSA_SLAM_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "msa-slam"


def _read_meta(seq_dir: Path) -> dict | None:
    try:
        return json.loads((seq_dir / META_FILE).read_text())
    except (OSError, ValueError):
        return None


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
    return (meta.get("frames") == len(sizes) == len(list(velodyne.glob("*.bin")))
            and all(_scan_size(velodyne / f"{k:06d}.bin") == size for k, size in enumerate(sizes))
            and all(_scan_size(point_times / f"{k:06d}.npy") == size for k, size in enumerate(times_sizes))
            and (seq_dir / "poses.txt").is_file() and (seq_dir / "times.txt").is_file())


def _is_ours(seq_dir: Path, key: str) -> bool:
    """True when sim.json says `seq_dir` was simulated from this config (complete or since damaged)."""
    meta = _read_meta(seq_dir)
    return meta is not None and meta.get("key") == key


CALIB_TEXT = "".join(f"P{k}: 1 0 0 0 0 1 0 0 0 0 1 0\n" for k in range(4)) + "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n"


def _write(sim: Simulation, target: Path, progress: bool) -> None:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    (target / "velodyne").mkdir(parents=True)
    with Progress(TextColumn("[bold]simulating[/] {task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), disable=not progress, transient=False) as bar:
        task = bar.add_task(f"{sim.config.label} / {sim.config.sensor}", total=len(sim))
        sizes, times_sizes = [], []
        for k in range(len(sim)):
            scan, point_times = sim.scan(k)
            scan.tofile(target / "velodyne" / f"{k:06d}.bin")
            sizes.append(scan.nbytes)
            if point_times is not None:
                (target / TIMES_FOLDER).mkdir(exist_ok=True)
                times_file = target / TIMES_FOLDER / f"{k:06d}.npy"
                np.save(times_file, point_times.astype(np.float32))
                times_sizes.append(times_file.stat().st_size)
            bar.advance(task)
    (target / "poses.txt").write_text(format_kitti(sim.poses))
    (target / "times.txt").write_text("".join(f"{t:.6e}\n" for t in sim.times))
    (target / "calib.txt").write_text(CALIB_TEXT)
    kiss = target / "sequences" / "00"
    kiss.mkdir(parents=True)
    for name in ("velodyne", "calib.txt", "times.txt", "poses.txt", *([TIMES_FOLDER] if times_sizes else [])):
        (kiss / name).symlink_to(Path("..", "..", name))
    (target / "poses").mkdir()
    (target / "poses" / "00.txt").symlink_to(Path("..", "poses.txt"))
    meta = {
        "key": sim.config.key(), "sim_version": SIM_VERSION, "msa_slam_version": msa_slam.__version__,
        "config": sim.config.model_dump(), "frames": len(sim), "scan_bytes": sizes,
        "point_times_bytes": times_sizes or None,
        "source_frames": sim.frames.tolist(),
        "sensor": {"beams": sim.lidar.model.beams, "azimuth_steps": sim.lidar.model.azimuth_steps,
                   "max_range": sim.lidar.model.max_range},
        "world_triangles": sim.world.triangles,
        "trajectory_files_sha256": sim.config._files_sha256,
        "source": (f"trajectory file {sim.config.trajectory}" if sim.config.is_file
                   else KITTI_CITATION if sim.config.trajectory.startswith("kitti") else "procedural"),
    }
    (target / META_FILE).write_text(json.dumps(meta, indent=1))  # written last: marks completeness


def simulate_sequence(config: SimConfig, out: str | os.PathLike | None = None,
                      cache_dir: str | os.PathLike | None = None, progress: bool = False) -> Path:
    """Write (or reuse) the sequence of `config`; returns its directory.

    Without `out` the directory is <cache>/<trajectory>_<sensor>_<key>. An existing complete
    simulation of the same config is returned as is; one of the same config with a missing or truncated
    scan is simulated again (with a warning); any other existing non-empty `out` is an error.
    """
    key = config.key()
    target = Path(out) if out is not None else cache_root(cache_dir) / f"{config.label}_{config.sensor}_{key}"
    remove_orphans(target.parent, f".{target.name}.partial-*")
    if is_complete(target, key):
        return target
    damaged = _is_ours(target, key)
    if damaged:
        log.warning("%s: a scan is missing or truncated (sizes differ from %s); simulating it again",
                    target, META_FILE)
    elif target.exists() and (not target.is_dir() or any(target.iterdir())):
        raise InputError(f"{target}: exists and is not a complete simulation of this config (key {key}); "
                         "remove it or choose another output directory")
    sim = prepare(config)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        with partial_dir(target.parent, target.name) as tmp:
            _write(sim, tmp / "seq", progress)
            if damaged:
                os.replace(target, tmp / "damaged")  # removed with the scratch folder
            elif target.exists():
                target.rmdir()  # an empty directory (checked above) is replaced
            os.replace(tmp / "seq", target)
    except OSError as exc:
        if is_complete(target, key):  # a concurrent writer finished first
            return target
        raise InputError(f"{target}: cannot write the simulated sequence ({exc.strerror or exc}); "
                         "choose a writable --out or cache folder (MSA_SLAM_CACHE)") from None
    return target


# The embedded defaults (see docs in `default_sequence`).
DEFAULT_CONFIGS: dict[str, SimConfig] = {
    "demo": SimConfig(trajectory="kitti-06", sensor="hdl64", stride=1, azimuth_steps=720),
    "test": SimConfig(trajectory="figure-eight", sensor="hdl64", stride=2, azimuth_steps=360, realism="clean"),
}


def default_sequence(kind: str = "demo", cache_dir: str | os.PathLike | None = None,
                     progress: bool = False) -> Path:
    """The embedded default sequence, simulated on first use and cached.

    "demo": the whole KITTI-06 trajectory (1.2 km, a loop driven in both directions: revisits along most of
    it) at the native 10 Hz, 1101 scans, HDL-64 beams with 720 azimuth steps (0.5 deg, ~40k points a scan),
    realism preset "kitti" (motion distortion, sensor imperfections, a changing world); `msa-slam demo` from
    an empty cache (simulation ~50 s, KISS-ICP at 1 thread ~80 s, descriptors, 7 methods) takes ~3 minutes on
    2 cores.
    "test": the procedural figure-eight (revisits at its crossing and where it closes) at every 2nd
    frame, 209 scans ~2 m apart, HDL-64 beams with 360 azimuth steps (1 deg), realism preset "clean" (the
    plain simulator the pipeline tests were written against): a few seconds to make.
    """
    if kind not in DEFAULT_CONFIGS:
        raise InputError(f"unknown default sequence {kind!r}; choose one of {', '.join(DEFAULT_CONFIGS)}")
    return simulate_sequence(DEFAULT_CONFIGS[kind], cache_dir=cache_dir, progress=progress)
