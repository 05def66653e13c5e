"""Spinning LiDAR models ray cast with Embree: beam elevations, azimuth steps, range limits, noise, and the
imperfections of a real sensor.

HDL-64E-like (KITTI: 64 beams from +2 to -24.8 deg), Ouster OS1-64 / OS1-128-like (+-22.5 deg).
A sweep casts every (beam, azimuth) ray against the world in one batched call, each column from the pose
at its firing time when motion distortion is on, keeps the first hit within [min_range, max_range],
applies the `SensorRealism` effects, perturbs ranges with noise, drops a random fraction, and returns
float32 points as the sensor reports them (each in the sensor frame at its own firing time, not deskewed)
with an intensity from surface reflectance and incidence, and each point's time from the sweep start.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TypeVar

import numpy as np

from msa_slam.errors import InputError
from msa_slam.sim.scan import PoseAt, column_times, fixed_pose, lost_returns, mixed_pixels, range_sigma, sweep_rays
from msa_slam.sim.shapes import Material
from msa_slam.sim.world import World
from msa_slam.types import validate_pose, validate_poses

T = TypeVar("T")

CALIBRATION_STREAM = 2**40  # seeds the per-sequence calibration errors apart from any per-frame stream
MAX_AZIMUTH_STEPS = 8192  # columns a revolution: beyond any spinning LiDAR (Ouster 2048, an HDL-64E at 5 Hz ~4500);
# memory grows with beams x columns, and 10^7 columns exhausted this 24 GiB machine


@dataclass(frozen=True)
class LidarModel:
    """A spinning LiDAR: elevations in degrees (one per beam) and the ray-casting parameters."""

    name: str
    elevations_deg: tuple[float, ...]
    azimuth_steps: int = 1024
    max_range: float = 120.0
    min_range: float = 1.0
    range_noise: float = 0.02
    dropout: float = 0.0
    sweep_period: float = 0.1  # s per revolution (10 Hz)

    def __post_init__(self) -> None:
        if not 8 <= self.azimuth_steps <= MAX_AZIMUTH_STEPS:
            raise InputError(
                f"sensor {self.name}: azimuth_steps must be in 8..{MAX_AZIMUTH_STEPS}, got {self.azimuth_steps}"
            )
        if not 0 < self.min_range < self.max_range:
            raise InputError(
                f"sensor {self.name}: need 0 < min_range < max_range, got {self.min_range} and {self.max_range}"
            )
        if not 0 <= self.range_noise < float("inf"):  # NaN fails too
            raise InputError(f"sensor {self.name}: range_noise must be finite and >= 0, got {self.range_noise}")
        if not 0 <= self.dropout < 1:
            raise InputError(f"sensor {self.name}: dropout must be in [0, 1), got {self.dropout}")
        if not self.sweep_period > 0:
            raise InputError(f"sensor {self.name}: sweep_period must be > 0 s, got {self.sweep_period}")

    @property
    def beams(self) -> int:
        return len(self.elevations_deg)

    def directions(
        self, elevation_offsets_deg: np.ndarray | None = None, azimuth_offsets_deg: np.ndarray | None = None
    ) -> np.ndarray:
        """(beams * azimuth_steps, 3) unit ray directions in the sensor frame (x forward, z up), beam-major,
        optionally with per-beam angle offsets (degrees)."""
        elev = np.asarray(self.elevations_deg, dtype=np.float64)
        if elevation_offsets_deg is not None:
            elev = elev + elevation_offsets_deg
        elev = np.radians(elev)[:, None]
        azim = np.linspace(0.0, 2 * np.pi, self.azimuth_steps, endpoint=False)[None, :]
        if azimuth_offsets_deg is not None:
            azim = azim + np.radians(azimuth_offsets_deg)[:, None]
        dirs = np.stack(
            np.broadcast_arrays(np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)), axis=-1
        )
        return dirs.reshape(-1, 3)


@dataclass(frozen=True)
class SensorRealism:
    """Every sensor imperfection; each default is "off", and all off give today's scans.

    Calibration errors are drawn once per sequence (from the Lidar's seed); the rest per scan.
    """

    motion_distortion: bool = False  # cast each azimuth column from the pose at its firing time
    elevation_bias_deg: float = 0.0  # reported minus true elevation, all beams (KITTI's HDL-64: ~ -0.22)
    elevation_sigma_deg: float = 0.0  # per-beam elevation errors (std)
    azimuth_sigma_deg: float = 0.0  # per-beam azimuth errors (std)
    range_bias_sigma: float = 0.0  # m: per-beam range bias (std)
    range_noise_per_m: float = 0.0  # noise std added per metre of range (on top of the model's range_noise)
    incidence_noise: float = 0.0  # noise std per metre of range per unit tan(incidence)
    min_return_power: float = 0.0  # returns at this relative power are lost half the time (dark, grazing)
    mixed_pixel_prob: float = 0.0  # chance a return at a depth edge reports a range between both surfaces
    mixed_pixel_edge: float = 0.5  # m: range jump to an azimuth neighbour that makes a depth edge
    vegetation_dropout: float = 0.0  # chance a return from foliage is lost, per scan and ray
    vegetation_depth: float = 0.0  # m: mean extra range of foliage returns (the beam enters the crown)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name != "elevation_bias_deg" and not isinstance(value, bool) and not 0 <= value < float("inf"):
                raise InputError(f"sensor realism: {f.name} must be finite and >= 0, got {value}")
        for name in ("mixed_pixel_prob", "vegetation_dropout"):
            if not getattr(self, name) < 1:
                raise InputError(f"sensor realism: {name} must be in [0, 1), got {getattr(self, name)}")
        if not abs(self.elevation_bias_deg) < 5:
            raise InputError(
                f"sensor realism: elevation_bias_deg must be within +-5 deg, got {self.elevation_bias_deg}"
            )
        if not self.mixed_pixel_edge > 0:
            raise InputError(f"sensor realism: mixed_pixel_edge must be > 0 m, got {self.mixed_pixel_edge}")

    @classmethod
    def clean(cls) -> SensorRealism:
        """Everything off: the ideal sensor of the plain simulator."""
        return cls()


# HDL-64E: an upper block of 32 lasers at ~1/3 deg spacing down to -8.33 deg and a lower block of 32 at
# ~1/2 deg down to -24.8 deg (the KITTI field of view); Ouster OS1: uniform over +-22.5 deg.
_HDL64_ELEVATIONS = np.concatenate([np.linspace(2.0, -8.33, 32), np.linspace(-8.83, -24.8, 32)])
SENSORS: dict[str, LidarModel] = {
    "hdl64": LidarModel("hdl64", tuple(_HDL64_ELEVATIONS.round(4)), 1800, 120.0),
    "os1-64": LidarModel("os1-64", tuple(np.linspace(22.5, -22.5, 64).round(4)), 1024, 120.0),
    "os1-128": LidarModel("os1-128", tuple(np.linspace(22.5, -22.5, 128).round(4)), 1024, 120.0),
}


def get_sensor(
    name: str,
    azimuth_steps: int | None = None,
    max_range: float | None = None,
    min_range: float | None = None,
    range_noise: float | None = None,
    dropout: float | None = None,
    sweep_period: float | None = None,
) -> LidarModel:
    """The named sensor with the overrides given (None: the sensor's own value)."""
    if name not in SENSORS:
        raise InputError(f"unknown sensor {name!r}; choose one of {', '.join(SENSORS)}")
    model = SENSORS[name]
    return replace(
        model,
        azimuth_steps=_given(azimuth_steps, model.azimuth_steps),
        max_range=_given(max_range, model.max_range),
        min_range=_given(min_range, model.min_range),
        range_noise=_given(range_noise, model.range_noise),
        dropout=_given(dropout, model.dropout),
        sweep_period=_given(sweep_period, model.sweep_period),
    )


def _given(value: T | None, default: T) -> T:
    return default if value is None else value


class Lidar:
    """A sensor model bound to a world, with its per-sequence calibration errors drawn from `seed`.

    `sweep(pose_at, t, rng)` gives a scan of a moving sensor and its per-point times; `scan(pose, rng)`
    the scan from one fixed pose.
    """

    def __init__(
        self, model: LidarModel, world: World, realism: SensorRealism = SensorRealism(), seed: int = 0
    ) -> None:
        self.model = model
        self.world = world
        self.realism = realism
        self._dirs = model.directions()  # as reported: the nominal beam angles
        cal = np.random.default_rng([seed, CALIBRATION_STREAM])
        elev_err = realism.elevation_bias_deg + realism.elevation_sigma_deg * cal.standard_normal(model.beams)
        azim_err = realism.azimuth_sigma_deg * cal.standard_normal(model.beams)
        self.range_bias = realism.range_bias_sigma * cal.standard_normal(model.beams)
        calibrated = not (elev_err.any() or azim_err.any())
        # the rays really leave at the nominal angles minus the errors the driver does not know about
        self._cast_dirs = self._dirs if calibrated else model.directions(-elev_err, -azim_err)
        self.column_times = column_times(model.azimuth_steps, model.sweep_period)

    def scan(self, pose: np.ndarray, rng: np.random.Generator, time: float = 0.0) -> np.ndarray:
        """(P, 4) float32 x, y, z, intensity of a sensor standing still at `pose` at `time` (where the world's
        moving objects are then)."""
        return self.sweep(fixed_pose(validate_pose(pose, "sensor pose")), time, rng)[0]

    def sweep(self, pose_at: PoseAt, t: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One revolution whose forward-facing column fires at `t` (the scan's timestamp, as in KITTI), so it
        runs from t - period / 2: (P, 4) float32 x, y, z, intensity as reported (each point in the sensor
        frame at its firing time) and (P,) float64 firing times in seconds from the sweep start.
        `pose_at(times)` gives (k, 4, 4) world-from-sensor poses on the trajectory's clock."""
        m, r = self.model, self.realism
        if r.motion_distortion:
            start = t - m.sweep_period / 2
            poses = validate_poses(pose_at(start + self.column_times), "sensor poses")
            origins, dirs_world = sweep_rays(poses, self._cast_dirs)
        else:
            pose = validate_pose(pose_at(np.array([t]))[0], "sensor pose")
            origins = pose[:3, 3]
            # einsum, not matmul: BLAS threads for this small product stall badly on a busy machine
            dirs_world = np.einsum("ij,kj->ki", pose[:3, :3], self._cast_dirs)
        hits = self.world.cast(origins, dirs_world, t)  # ray order: beam-major
        ranges, ray_idx = hits.dist, hits.ray
        keep = (ranges >= m.min_range) & (ranges <= m.max_range)
        if m.dropout > 0:
            keep &= rng.random(len(ranges)) >= m.dropout
        cos_inc = np.abs(np.einsum("ij,ij->i", hits.normal, dirs_world[ray_idx]))
        reflectance, material, normal = hits.reflectance, hits.material, hits.normal
        ranges, ray_idx, cos_inc, reflectance, material, normal = (
            a[keep] for a in (ranges, ray_idx, cos_inc, reflectance, material, normal)
        )
        lost = np.zeros(len(ranges), dtype=bool)
        if r.min_return_power > 0:
            lost |= lost_returns(reflectance, cos_inc, ranges, r.min_return_power, rng)
        foliage = material == Material.VEGETATION
        if r.vegetation_dropout > 0:
            lost |= foliage & (rng.random(len(ranges)) < r.vegetation_dropout)
        if lost.any():
            ranges, ray_idx, cos_inc, reflectance, foliage, normal = (
                a[~lost] for a in (ranges, ray_idx, cos_inc, reflectance, foliage, normal)
            )
        surface = ranges  # where each ray met its surface (the mixed pixels' edges are between surfaces)
        if r.vegetation_depth > 0:
            ranges = ranges + foliage * rng.exponential(r.vegetation_depth, len(ranges))
        if r.mixed_pixel_prob > 0:
            starts = np.broadcast_to(origins, dirs_world.shape)

            def hit_points(rows: np.ndarray) -> np.ndarray:
                return starts[ray_idx[rows]] + surface[rows, None] * dirs_world[ray_idx[rows]]

            ranges = mixed_pixels(
                ranges,
                ray_idx,
                (m.beams, m.azimuth_steps),
                r.mixed_pixel_edge,
                r.mixed_pixel_prob,
                rng,
                hit_points,
                normal,
            )
        sigma = (
            range_sigma(m.range_noise, r.range_noise_per_m, r.incidence_noise, ranges, cos_inc)
            if r.range_noise_per_m > 0 or r.incidence_noise > 0
            else m.range_noise
        )
        if np.any(sigma > 0):
            ranges = ranges + rng.normal(0.0, sigma, len(ranges))
        if r.range_bias_sigma > 0:
            ranges = ranges + self.range_bias[ray_idx // m.azimuth_steps]
        out = np.empty((len(ranges), 4), dtype=np.float32)
        out[:, :3] = self._dirs[ray_idx] * ranges[:, None]
        out[:, 3] = reflectance * (0.3 + 0.7 * cos_inc)
        return out, self.column_times[ray_idx % m.azimuth_steps]
