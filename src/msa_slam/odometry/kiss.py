"""LiDAR odometry with KISS-ICP (Vizzo et al., RA-L 2023), or odometry read from a pose file."""

from __future__ import annotations

import inspect
import logging
import math
import os
from typing import Any

import kiss_icp
import numpy as np
from kiss_icp.config.config import AdaptiveThresholdConfig, DataConfig, MappingConfig, RegistrationConfig
from kiss_icp.config.parser import KISSConfig
from kiss_icp.kiss_icp import KissICP

from msa_slam.errors import InputError
from msa_slam.io.poses import read_poses
from msa_slam.types import as_points

log = logging.getLogger(__name__)

MAX_LOGGED_FRAMES = 5  # frames whose registration problems are logged one by one; the rest are only counted
_process_threads: int | None = None  # KISS-ICP's thread count, fixed for the whole process at first use


def _number(name: str, value: Any, low: float = 0.0, strict: bool = True) -> float:
    """`value` as a finite float > low (>= low unless strict), else an InputError naming the parameter."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or (value <= low if strict else value < low):
        bound = f"> {low}" if strict else f">= {low}"
        raise InputError(f"odometry {name}={value!r}: must be a finite number {bound}")
    return float(value)


def _count(name: str, value: Any, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise InputError(f"odometry {name}={value!r}: must be an integer >= {low}")
    return int(value)


class KissOdometry:
    """KISS-ICP with every setting explicit; `register(points)` returns the world-from-LiDAR pose of that scan.

    The configuration is built from these arguments only (KISS-ICP's own defaults written out), never from
    `load_config`, which reads `kiss_icp_*` environment variables that would change results unseen.
    Deskewing is off by default (scans without per-point times); the voxel size follows KISS-ICP's rule
    max_range / 100 unless given. `num_threads=1` (default) keeps the ICP reductions in a fixed order, so
    identical runs give identical poses; 0 (KISS-ICP's "all cores") is faster but differs between runs
    by rounding, which keyframe sampling can turn into different keyframes. KISS-ICP sets its (TBB) thread
    count once per process, at its first use, so a later instance asking for another count is refused.
    """

    def __init__(self, max_range: float = 100.0, min_range: float = 0.0, voxel_size: float | None = None,
                 deskew: bool = False, num_threads: int = 1, max_points_per_voxel: int = 20,
                 max_num_iterations: int = 500, convergence_criterion: float = 1e-4,
                 initial_threshold: float = 2.0, min_motion_th: float = 0.1,
                 fixed_threshold: float | None = None) -> None:
        max_range = _number("max_range", max_range)
        min_range = _number("min_range", min_range, strict=False)
        if not min_range < max_range:
            raise InputError(f"KISS-ICP needs 0 <= min_range < max_range, got {min_range} and {max_range}")
        if not isinstance(deskew, bool):
            raise InputError(f"odometry deskew={deskew!r}: must be true or false")
        config = KISSConfig.model_construct(  # model_construct: no settings sources (environment, .env)
            out_dir="results",
            data=DataConfig(max_range=max_range, min_range=min_range, deskew=deskew),
            mapping=MappingConfig(
                voxel_size=max_range / 100.0 if voxel_size is None else _number("voxel_size", voxel_size),
                max_points_per_voxel=_count("max_points_per_voxel", max_points_per_voxel, 1)),
            registration=RegistrationConfig(
                max_num_iterations=_count("max_num_iterations", max_num_iterations, 1),
                convergence_criterion=_number("convergence_criterion", convergence_criterion),
                max_num_threads=_count("num_threads", num_threads, 0)),
            adaptive_threshold=AdaptiveThresholdConfig(
                fixed_threshold=None if fixed_threshold is None else _number("fixed_threshold", fixed_threshold),
                initial_threshold=_number("initial_threshold", initial_threshold),
                min_motion_th=_number("min_motion_th", min_motion_th, strict=False)),
        )
        _claim_threads(config.registration.max_num_threads)
        self._icp = KissICP(config)
        self._frames = 0
        self.unregistered_frames: list[int] = []  # frames with no points to register: pose extrapolated

    @property
    def params(self) -> dict[str, Any]:
        """Every constructor argument with its effective value: `KissOdometry(**params)` rebuilds this setup
        (what a re-loadable config.yaml should record as odometry_params)."""
        c = self._icp.config
        return {"max_range": c.data.max_range, "min_range": c.data.min_range, "voxel_size": c.mapping.voxel_size,
                "deskew": c.data.deskew, "num_threads": c.registration.max_num_threads,
                "max_points_per_voxel": c.mapping.max_points_per_voxel,
                "max_num_iterations": c.registration.max_num_iterations,
                "convergence_criterion": c.registration.convergence_criterion,
                "initial_threshold": c.adaptive_threshold.initial_threshold,
                "min_motion_th": c.adaptive_threshold.min_motion_th,
                "fixed_threshold": c.adaptive_threshold.fixed_threshold}

    @property
    def config(self) -> dict[str, Any]:
        """The full effective KISS-ICP configuration, thread count and version (identifies cached results)."""
        settings = self._icp.config.model_dump()
        settings.pop("out_dir", None)
        return {"method": "kiss_icp", "kiss_icp_version": kiss_icp.__version__, **settings}

    def register(self, points: np.ndarray, timestamps: np.ndarray | None = None) -> np.ndarray:
        """Register the next scan (sensor frame); return its (4, 4) world-from-LiDAR pose.

        KISS-ICP does not report whether its ICP converged; what it does expose is the set of points it
        registered: a frame with none (all outside [min_range, max_range]) only gets the constant-velocity
        prediction, which is logged as a warning and listed in `unregistered_frames`.
        """
        cloud = as_points(points, where=f"odometry frame {self._frames}")
        stamps = np.zeros(0) if timestamps is None else np.asarray(timestamps, dtype=np.float64).ravel()
        _, source = self._icp.register_frame(cloud, stamps)
        if len(source) == 0 and self._frames > 0:
            self._not_registered(len(cloud))
        self._frames += 1
        return np.array(self._icp.last_pose, dtype=np.float64)

    def _not_registered(self, n_points: int) -> None:
        self.unregistered_frames.append(self._frames)
        if len(self.unregistered_frames) <= MAX_LOGGED_FRAMES:
            data = self._icp.config.data
            more = " (further such frames are not logged)" if len(self.unregistered_frames) == MAX_LOGGED_FRAMES else ""
            log.warning("KISS-ICP frame %d: none of its %d points lies within %g-%g m, so it was not registered "
                        "(pose extrapolated at constant velocity)%s", self._frames, n_points, data.min_range,
                        data.max_range, more)


PARAMETERS = tuple(inspect.signature(KissOdometry).parameters)  # the odometry_params KissOdometry takes


def _claim_threads(num_threads: int) -> None:
    """Record the process's KISS-ICP thread count; refuse another one (KISS-ICP would silently keep the first)."""
    global _process_threads
    if _process_threads is None:
        _process_threads = num_threads
    elif _process_threads != num_threads:
        raise InputError(f"odometry num_threads={num_threads}: KISS-ICP already runs with num_threads="
                         f"{_process_threads} in this process and cannot change it; use a separate process")


class PosesFromFile:
    """Odometry taken from a KITTI or TUM pose file: frame i gets line i."""

    def __init__(self, path: str | os.PathLike, fmt: str = "auto") -> None:
        self.path = os.fspath(path)
        self.poses, self.times = read_poses(path, fmt)
        self._frames = 0

    @property
    def config(self) -> dict[str, Any]:
        return {"method": "pose_file", "path": os.path.abspath(self.path)}

    def __len__(self) -> int:
        return len(self.poses)

    def register(self, points: np.ndarray | None = None, timestamps: np.ndarray | None = None) -> np.ndarray:
        """Return the next pose of the file (the scan itself is not needed)."""
        if self._frames >= len(self.poses):
            raise InputError(f"{self.path}: has {len(self.poses)} poses but frame {self._frames} was requested")
        pose = self.poses[self._frames].copy()
        self._frames += 1
        return pose
