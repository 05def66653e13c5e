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
from msa_slam.odometry.deskew import deskew, se3_log
from msa_slam.types import as_points

log = logging.getLogger(__name__)

# Logged when deskew is switched off for scans without per-point times (and put in the run's report by the pipelines)
NO_POINT_TIMES = "odometry: no per-point times: deskewing has no effect (recorded as deskew false)"
MAX_LOGGED_FRAMES = 5  # frames whose registration problems are logged one by one; the rest are only counted
# The fewest points within range a scan is registered with: point-to-point ICP needs three (not on a line) to fix
# a rigid transform; KISS-ICP registers any non-empty scan, and one or two points leave its pose unconstrained.
MIN_REGISTRATION_POINTS = 3
RANGE_CHECK_POINTS = 1024  # a scan's points counted in range before the rest (KissOdometry._registrable)
DEFAULT_THREADS = 1  # KISS-ICP's threads unless asked: reproducible poses (see KissOdometry)
_process_threads: int | None = None  # KISS-ICP's thread count, fixed for the whole process at first use


def _number(name: str, value: Any, low: float = 0.0, strict: bool = True) -> float:
    """`value` as a finite float > low (>= low unless strict), else an InputError naming the parameter."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or (value <= low if strict else value < low)
    ):
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
    Deskewing is off unless asked for here, where the scans are not known yet; the pipelines ask for it when
    the source's frames carry per-point times, as kiss-icp does (odometry.choice.make_odometry); see
    `register` for the sweep time convention. The voxel size follows KISS-ICP's rule
    max_range / 100 unless given. `num_threads=1` (default) keeps the ICP reductions in a fixed order, so
    identical runs give identical poses; 0 (KISS-ICP's "all cores") is faster but differs between runs
    by rounding, which keyframe sampling can turn into different keyframes. KISS-ICP sets its (TBB) thread
    count once per process, at its first use, so a later instance asking for another count is refused.
    """

    def __init__(
        self,
        max_range: float = 100.0,
        min_range: float = 0.0,
        voxel_size: float | None = None,
        deskew: bool = False,
        num_threads: int = DEFAULT_THREADS,
        max_points_per_voxel: int = 20,
        max_num_iterations: int = 500,
        convergence_criterion: float = 1e-4,
        initial_threshold: float = 2.0,
        min_motion_th: float = 0.1,
        fixed_threshold: float | None = None,
    ) -> None:
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
                max_points_per_voxel=_count("max_points_per_voxel", max_points_per_voxel, 1),
            ),
            registration=RegistrationConfig(
                max_num_iterations=_count("max_num_iterations", max_num_iterations, 1),
                convergence_criterion=_number("convergence_criterion", convergence_criterion),
                max_num_threads=_count("num_threads", num_threads, 0),
            ),
            adaptive_threshold=AdaptiveThresholdConfig(
                fixed_threshold=None if fixed_threshold is None else _number("fixed_threshold", fixed_threshold),
                initial_threshold=_number("initial_threshold", initial_threshold),
                min_motion_th=_number("min_motion_th", min_motion_th, strict=False),
            ),
        )
        _claim_threads(config.registration.max_num_threads)
        self._icp = KissICP(config)
        self._frames = 0
        self._last_time: float | None = None  # scan time of the previous frame (deskew: sweep / frame interval)
        self._first: list[tuple[np.ndarray, np.ndarray | None, float | None]] = []  # frames 0-1, see _restart_deskewed
        self.unregistered_frames: list[int] = []  # frames with no points to register: pose extrapolated

    @property
    def params(self) -> dict[str, Any]:
        """Every constructor argument with its effective value: `KissOdometry(**params)` rebuilds this setup
        (what a re-loadable config.yaml should record as odometry_params)."""
        c = self._icp.config
        return {
            "max_range": c.data.max_range,
            "min_range": c.data.min_range,
            "voxel_size": c.mapping.voxel_size,
            "deskew": c.data.deskew,
            "num_threads": c.registration.max_num_threads,
            "max_points_per_voxel": c.mapping.max_points_per_voxel,
            "max_num_iterations": c.registration.max_num_iterations,
            "convergence_criterion": c.registration.convergence_criterion,
            "initial_threshold": c.adaptive_threshold.initial_threshold,
            "min_motion_th": c.adaptive_threshold.min_motion_th,
            "fixed_threshold": c.adaptive_threshold.fixed_threshold,
        }

    @property
    def config(self) -> dict[str, Any]:
        """The full effective KISS-ICP configuration, thread count and version (identifies cached results)."""
        settings = self._icp.config.model_dump()
        settings.pop("out_dir", None)
        if settings["data"]["deskew"]:  # not KISS-ICP's own end-of-sweep deskew (see register)
            settings["data"]["deskew_reference"] = "mid-sweep"
        return {"method": "kiss_icp", "kiss_icp_version": kiss_icp.__version__, **settings}

    def register(
        self, points: np.ndarray, timestamps: np.ndarray | None = None, time: float | None = None
    ) -> np.ndarray:
        """Register the next scan (sensor frame); return its (4, 4) world-from-LiDAR pose.

        With deskew on and per-point `timestamps` (s from the sweep start), the pose is that of mid-sweep,
        the time KITTI's (and the simulator's) scan timestamp and ground truth refer to. KISS-ICP 1.3 alone
        deskews to the sweep's END (its times normalised to [0, 1], 1 = no correction), so its poses would
        lead the ground truth by half a sweep, and frames 0-1 (no motion known yet) would stay distorted
        in the map. `time` (the scan's timestamp, s) scales the motion to the sweep:
        with every 2nd scan read (--jump 2) a sweep covers half the interval between frames.

        KISS-ICP does not report whether its ICP converged; what can be checked is what it registers: a scan
        with fewer than MIN_REGISTRATION_POINTS points within (min_range, max_range) is not registered (nor
        mapped) and only gets the constant-velocity prediction, as KISS-ICP does for an empty scan; such a
        frame is logged as a warning and listed in `unregistered_frames` (for the run's notes). The run goes
        on: a scan or two a sensor hardly saw is not fatal in a recording.
        """
        cloud = as_points(points, where=f"odometry frame {self._frames}")
        if self._frames == 0 and timestamps is None and self._icp.config.data.deskew:
            raise InputError(
                "odometry frame 0: deskew is on but the scan has no per-point times; call "
                "without_point_times() first for a source without them (the pipelines do for a "
                "FrameSource with point_times=False, see odometry.choice.make_odometry) or give "
                "deskew=False"
            )
        stamps = None
        if self._icp.config.data.deskew and timestamps is not None:
            stamps = self._point_times(timestamps, len(cloud))
            if self._frames >= 2:
                cloud = self._deskew(cloud, stamps, self._sweep_share(stamps, time), self._icp.last_delta)
        registered, in_range = self._registrable(cloud)
        # no times: KISS-ICP's own deskew skipped; no points: KISS-ICP predicts the pose at constant velocity
        self._icp.register_frame(registered, np.zeros(0))
        if in_range < MIN_REGISTRATION_POINTS:
            self._not_registered(in_range, len(cloud))
        if self._frames < 2:
            self._first.append((cloud, stamps, time))
            timed = [(c, s, t) for c, s, t in self._first if s is not None]
            if self._frames == 1 and len(timed) == len(self._first):
                self._restart_deskewed(timed)
        self._frames += 1
        self._last_time = None if time is None else float(time)
        return np.array(self._icp.last_pose, dtype=np.float64)

    def without_point_times(self) -> None:
        """The scans carry no per-point times, so deskewing (which needs them) cannot be done: switch it off,
        with one warning, before the first scan and any cache key, so that the configuration recorded with the
        results and in cache keys says what was done (the poses are those of deskew off). `register` refuses
        deskew on a first scan without per-point times rather than record a deskew it did not do."""
        if self._icp.config.data.deskew:
            log.warning(NO_POINT_TIMES)
            self._icp.config.data.deskew = False

    def _restart_deskewed(self, first: list[tuple[np.ndarray, np.ndarray, float | None]]) -> None:
        """Frames 0 and 1 come before any motion is known, so they are registered raw; a map built from
        them would hold their distortion for as long as it keeps their points, and later (deskewed) scans
        would be registered against a distorted map. Once frame 1 gives the motion, KISS-ICP starts over
        with both deskewed by it (`first`: frames 0 and 1, both with per-point times)."""
        (cloud0, stamps0, time0), (cloud1, stamps1, time1) = first
        motion = self._icp.last_delta.copy()
        self._icp = KissICP(self._icp.config)
        self._last_time = None if time0 is None else float(time0)
        share = self._sweep_share(stamps1, time1)
        for cloud, stamps in ((cloud0, stamps0), (cloud1, stamps1)):
            self._icp.register_frame(self._registrable(self._deskew(cloud, stamps, share, motion))[0], np.zeros(0))
        self._first.clear()

    def _registrable(self, cloud: np.ndarray) -> tuple[np.ndarray, int]:
        """(`cloud`, or no points when fewer than MIN_REGISTRATION_POINTS are in range; how many are in range,
        counted no further than the first RANGE_CHECK_POINTS when they hold enough): KISS-ICP keeps the points
        strictly between min_range and max_range. A scan's first points nearly always settle it, and counting
        them all took half a millisecond a scan on the odometry's critical path."""
        in_range = self._in_range(cloud[:RANGE_CHECK_POINTS])
        if in_range < MIN_REGISTRATION_POINTS and len(cloud) > RANGE_CHECK_POINTS:
            in_range += self._in_range(cloud[RANGE_CHECK_POINTS:])
        return (cloud if in_range >= MIN_REGISTRATION_POINTS else cloud[:0]), in_range

    def _in_range(self, cloud: np.ndarray) -> int:
        """How many of `cloud`'s points lie strictly between min_range and max_range."""
        data = self._icp.config.data
        squared = np.einsum("ij,ij->i", cloud, cloud)
        return int(np.count_nonzero((squared > data.min_range**2) & (squared < data.max_range**2)))

    def _point_times(self, timestamps: np.ndarray, n_points: int) -> np.ndarray:
        stamps = np.asarray(timestamps, dtype=np.float64).ravel()
        if len(stamps) != n_points or not np.isfinite(stamps).all():
            raise InputError(
                f"odometry frame {self._frames}: {len(stamps)} per-point times for {n_points} "
                "points; deskewing needs one finite time (s) a point"
            )
        return stamps

    def _sweep_share(self, stamps: np.ndarray, time: float | None) -> float:
        """Share of the interval since the previous frame that the sweep took (1: unknown, or a sweep per
        frame interval)."""
        span = float(stamps.max() - stamps.min()) if len(stamps) else 0.0
        if time is not None and self._last_time is not None and time > self._last_time:
            return min(1.0, span / (time - self._last_time))
        return 1.0

    @staticmethod
    def _deskew(cloud: np.ndarray, stamps: np.ndarray, share: float, motion: np.ndarray) -> np.ndarray:
        """Each point moved into the sensor frame of mid-sweep (midway between the first and last point's
        time), at the constant velocity of `motion` (a frame interval's), `share` of it during the sweep."""
        span = float(stamps.max() - stamps.min()) if len(stamps) else 0.0
        if span <= 0.0:  # one time for all points: nothing to correct (KISS-ICP would divide by zero)
            return cloud
        rho, phi = se3_log(motion)
        return deskew(cloud, (stamps - stamps.min()) / span, share * rho, share * phi)

    def unregistered_warning(self, frames: int) -> list[str]:
        """One line on the frames that were not registered (none: []), for the run's notes: a cached run logs
        nothing per frame, so this is where its report learns of them."""
        if not self.unregistered_frames:
            return []
        data, listed = self._icp.config.data, self.unregistered_frames
        shown = ", ".join(map(str, listed[:MAX_LOGGED_FRAMES])) + (
            f" and {len(listed) - MAX_LOGGED_FRAMES} more" if len(listed) > MAX_LOGGED_FRAMES else ""
        )
        which = f"frame{'s' * (len(listed) > 1)} {shown}"
        return [
            f"odometry: KISS-ICP could not register {len(listed)} of {frames} frames ({which}): fewer than "
            f"{MIN_REGISTRATION_POINTS} of their points lie within {data.min_range:g}-{data.max_range:g} m, so "
            f"their poses were extrapolated at constant velocity"
        ]

    def _not_registered(self, in_range: int, n_points: int) -> None:
        """List this frame as not registered, and log it (the first MAX_LOGGED_FRAMES such frames)."""
        self.unregistered_frames.append(self._frames)
        if len(self.unregistered_frames) <= MAX_LOGGED_FRAMES:
            data = self._icp.config.data
            more = " (further such frames are not logged)" if len(self.unregistered_frames) == MAX_LOGGED_FRAMES else ""
            span, needs = f"{data.min_range:g}-{data.max_range:g} m", f"registration needs {MIN_REGISTRATION_POINTS}"
            if in_range == 0:
                seen = f"none of its {n_points} points lies within {span}"
            elif in_range == n_points:
                seen = f"it has only {n_points} point{'s' * (n_points > 1)} ({needs})"
            else:
                seen = f"only {in_range} of its {n_points} points lie within {span} ({needs})"
            log.warning(
                "KISS-ICP frame %d: %s, so it was not registered (pose extrapolated at constant velocity)%s",
                self._frames,
                seen,
                more,
            )


PARAMETERS = tuple(inspect.signature(KissOdometry).parameters)  # the odometry_params KissOdometry takes


def _claim_threads(num_threads: int) -> None:
    """Record the process's KISS-ICP thread count; refuse another one (KISS-ICP would silently keep the first)."""
    global _process_threads
    if _process_threads is None:
        _process_threads = num_threads
    elif _process_threads != num_threads:
        raise InputError(
            f"odometry num_threads={num_threads}: KISS-ICP already runs with num_threads="
            f"{_process_threads} in this process and cannot change it; use a separate process"
        )


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

    def select(self, rows: np.ndarray) -> None:
        """Keep only the poses at `rows` (those of the scans a run reads: --first/--jump/-n)."""
        self.poses = self.poses[rows]
        self.times = None if self.times is None else self.times[rows]

    def register(
        self, points: np.ndarray | None = None, timestamps: np.ndarray | None = None, time: float | None = None
    ) -> np.ndarray:
        """Return the next pose of the file (the scan itself is not needed)."""
        if self._frames >= len(self.poses):
            raise InputError(f"{self.path}: has {len(self.poses)} poses but frame {self._frames} was requested")
        pose = self.poses[self._frames].copy()
        self._frames += 1
        return pose
