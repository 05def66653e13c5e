"""Spinning LiDAR models ray cast with Embree: beam elevations, azimuth steps, range limits and noise.

HDL-64E-like (KITTI: 64 beams from +2 to -24.8 deg), Ouster OS1-64 / OS1-128-like (+-22.5 deg).
A scan casts every (beam, azimuth) ray from the sensor origin against the world mesh, keeps the first
hit within [min_range, max_range], perturbs its range with Gaussian noise, drops a random fraction,
and returns float32 points in the sensor frame with an intensity from surface reflectance and incidence.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from msa_slam.errors import InputError
from msa_slam.sim.world import World
from msa_slam.types import validate_pose


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

    def __post_init__(self) -> None:
        if self.azimuth_steps < 8:
            raise InputError(f"sensor {self.name}: azimuth_steps must be >= 8, got {self.azimuth_steps}")
        if not 0 < self.min_range < self.max_range:
            raise InputError(f"sensor {self.name}: need 0 < min_range < max_range, got "
                             f"{self.min_range} and {self.max_range}")
        if self.range_noise < 0:
            raise InputError(f"sensor {self.name}: range_noise must be >= 0, got {self.range_noise}")
        if not 0 <= self.dropout < 1:
            raise InputError(f"sensor {self.name}: dropout must be in [0, 1), got {self.dropout}")

    @property
    def beams(self) -> int:
        return len(self.elevations_deg)

    def directions(self) -> np.ndarray:
        """(beams * azimuth_steps, 3) unit ray directions in the sensor frame (x forward, z up)."""
        elev = np.radians(np.asarray(self.elevations_deg))[:, None]
        azim = np.linspace(0.0, 2 * np.pi, self.azimuth_steps, endpoint=False)[None, :]
        dirs = np.stack(np.broadcast_arrays(np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim),
                                            np.sin(elev)), axis=-1)
        return dirs.reshape(-1, 3)


# HDL-64E: an upper block of 32 lasers at ~1/3 deg spacing down to -8.33 deg and a lower block of 32 at
# ~1/2 deg down to -24.8 deg (the KITTI field of view); Ouster OS1: uniform over +-22.5 deg.
_HDL64_ELEVATIONS = np.concatenate([np.linspace(2.0, -8.33, 32), np.linspace(-8.83, -24.8, 32)])
SENSORS: dict[str, LidarModel] = {
    "hdl64": LidarModel("hdl64", tuple(_HDL64_ELEVATIONS.round(4)), 1800, 120.0),
    "os1-64": LidarModel("os1-64", tuple(np.linspace(22.5, -22.5, 64).round(4)), 1024, 120.0),
    "os1-128": LidarModel("os1-128", tuple(np.linspace(22.5, -22.5, 128).round(4)), 1024, 120.0),
}


def get_sensor(name: str, **overrides: float | int | None) -> LidarModel:
    """The named sensor with any non-None overrides (azimuth_steps, max_range, range_noise, dropout)."""
    if name not in SENSORS:
        raise InputError(f"unknown sensor {name!r}; choose one of {', '.join(SENSORS)}")
    return replace(SENSORS[name], **{k: v for k, v in overrides.items() if v is not None})


class Lidar:
    """A sensor model bound to a world; `scan(pose, rng)` returns (P, 4) float32 x, y, z, intensity."""

    def __init__(self, model: LidarModel, world: World) -> None:
        self.model = model
        self.world = world
        self._dirs = model.directions()

    def scan(self, pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        pose = validate_pose(pose, "sensor pose")
        rot, origin = pose[:3, :3], pose[:3, 3]
        # einsum, not matmul: BLAS threads for this small product stall badly on a busy machine
        dirs_world = np.einsum("ij,kj->ki", rot, self._dirs)
        hit_tri, ray_idx, ranges = self.world.cast(origin, dirs_world)  # ray order: beam-major
        m = self.model
        keep = (ranges >= m.min_range) & (ranges <= m.max_range)
        if m.dropout > 0:
            keep &= rng.random(len(ranges)) >= m.dropout
        ranges, ray_idx, hit_tri = ranges[keep], ray_idx[keep], hit_tri[keep]
        if m.range_noise > 0:
            ranges = ranges + rng.normal(0.0, m.range_noise, len(ranges))
        dirs = self._dirs[ray_idx]
        cos_inc = np.abs(np.einsum("ij,ij->i", self.world.face_normals[hit_tri], dirs_world[ray_idx]))
        intensity = self.world.reflectance[hit_tri] * (0.3 + 0.7 * cos_inc)
        out = np.empty((len(ranges), 4), dtype=np.float32)
        out[:, :3] = dirs * ranges[:, None]
        out[:, 3] = intensity
        return out
