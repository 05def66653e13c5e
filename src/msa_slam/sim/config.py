"""What determines a simulated sequence: `SimConfig` (trajectory, sensor, frames, world seed, realism preset),
validated before any long work, and its cache key (the config, a trajectory file by content, the preset's
parameters, the simulator version, the fingerprint of the simulator's code and shipped trajectories, and the
libraries that ray-cast the scans)."""

from __future__ import annotations

import hashlib
from collections.abc import Collection
from dataclasses import asdict
from pathlib import Path

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from msa_slam.errors import InputError
from msa_slam.io.cache import cache_key
from msa_slam.io.fingerprint import code_fingerprint
from msa_slam.io.poses import POSE_FORMATS
from msa_slam.sim.layout import STYLES
from msa_slam.sim.realism import DEFAULT_REALISM, REALISM
from msa_slam.sim.sensors import SENSORS
from msa_slam.sim.trajectories import TRAJECTORY_NAMES, Trajectory, frame_indices, load_trajectory, read_trajectory

PARALLEL_MIN_FRAMES = 300  # fewer frames are simulated in the calling process (a worker's start-up costs seconds)

SIM_VERSION = "13"  # the generation of worlds and scans that docs and sim.json name: bump it when they change
SIM_LIBRARIES = ("trimesh", "embreex", "numpy", "scipy")  # ray casting, noise, poses (Rotation): the cache key
SIM_CODE = ("msa_slam.sim",)  # the simulator, and what it imports: the cache key
SIM_DATA = ("data/trajectories/*.npz",)  # the shipped trajectories it follows


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
    seed: int = Field(0, ge=0)  # numpy's generators take no negative seed
    azimuth_steps: int | None = None
    max_range: float | None = None
    range_noise: float = 0.02
    dropout: float = 0.0
    style: str | None = None  # None: "city" for vehicles, "campus" for walking platforms
    realism: str = DEFAULT_REALISM  # a preset of sim.realism: "kitti" (calibrated), "kitti-hard" or "clean"
    _files_sha256: str | None = PrivateAttr(default=None)  # content of the trajectory files: the cache key

    @field_validator("trajectory")
    @classmethod
    def _known_trajectory(cls, v: str) -> str:
        if v in TRAJECTORY_NAMES:
            return v
        path = Path(v).expanduser()
        if not path.is_file():
            looks_like_a_file = "/" in v or "." in v  # no shipped name has either
            what = "pose file not found:" if looks_like_a_file else "unknown trajectory"
            raise ValueError(
                f"{what} {v!r}; choose one of {', '.join(TRAJECTORY_NAMES)} or give a pose file (KITTI or TUM format)"
            )
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
    def _read_trajectory_file(self) -> SimConfig:
        """Check a trajectory file whole now (errors name its line, before any long work) and hash the files."""
        if self.trajectory in TRAJECTORY_NAMES:
            if self.times is not None or self.calib is not None or self.trajectory_format != "auto":
                raise ValueError(
                    f"times, calib and trajectory_format apply to a trajectory file, not to the "
                    f"shipped trajectory {self.trajectory!r}"
                )
            return self
        self.load_trajectory()
        parts = [
            f"{what}:{hashlib.sha256(Path(f).read_bytes()).hexdigest() if f else '-'}"
            for what, f in (("poses", self.trajectory), ("times", self.times), ("calib", self.calib))
        ]
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

    def frame_count(self) -> int:
        """How many scans the simulation casts (its trajectory's frames start..end by stride), known without
        casting, so that a run can check what it selects before the long work."""
        return len(frame_indices(len(self.load_trajectory()), self.start, self.end, self.stride, self.label))

    @field_validator("sensor", "realism", "style")
    @classmethod
    def _known_name(cls, v: str | None, info: ValidationInfo) -> str | None:
        choices: dict[str, tuple[str, Collection[str]]] = {
            "sensor": ("sensor", SENSORS),
            "realism": ("realism preset", REALISM),
            "style": ("world style", STYLES),
        }
        assert info.field_name is not None, "a field validator is told its field"
        kind, names = choices[info.field_name]
        if v is not None and v not in names:
            raise ValueError(f"unknown {kind} {v!r}; choose one of {', '.join(names)}")
        return v

    def key(self) -> str:
        """The cache key: hash of the config (a trajectory file by its content), the realism preset's parameters,
        the simulator version, the fingerprint of the simulator's code and shipped trajectories (SIM_CODE,
        SIM_DATA) and the versions of the libraries that ray-cast the scans."""
        config = self.model_dump()
        if self.is_file:  # the files' content, not where they are
            config.update(trajectory="file", times=None, calib=None, trajectory_files=self._files_sha256)
        preset = asdict(REALISM[self.realism])  # its parameters: retuning a preset is a new simulation
        return cache_key(
            "simulation",
            [],
            {"config": config, "realism_preset": preset, "sim_version": SIM_VERSION},
            code_fingerprint(SIM_CODE, SIM_DATA),
            SIM_LIBRARIES,
        )


def make_config(where: str = "simulation config", **fields: object) -> SimConfig:
    """A SimConfig, with validation problems reported as one InputError starting with `where` (a dataset spec
    names itself) and naming the parameters."""
    try:
        return SimConfig(**fields)
    except ValidationError as exc:
        problems = "; ".join(
            ": ".join([*([".".join(map(str, e["loc"]))] if e["loc"] else []), e["msg"].removeprefix("Value error, ")])
            for e in exc.errors()
        )
        raise InputError(f"{where}: {problems}") from None
