"""Frame sources and odometry for the online pipeline: scans arrive one at a time, as on a robot.

- A sequence folder or `sim:NAME` (msa_slam.pipeline.source; simulated sequences are cached on disk).
- `live:NAME[,field=value...,laps=K]`: the simulator's scans made in memory when the run asks for them,
  so long runs need no disk. With K laps the trajectory is driven forth, back, forth... (each pass
  reversed, so the path stays continuous and every pass revisits the whole route; each pass has its own
  sensor noise). `live:city-tour,laps=10` is a 22 km tour.
- `NoisyOdometry`: ground-truth motions with random per-step noise (a drifting odometry without the cost
  of KISS-ICP), for scale runs.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from msa_slam.datasets import Frame
from msa_slam.errors import InputError
from msa_slam.pipeline.source import open_sequence
from msa_slam.types import validate_poses

LIVE_PREFIX = "live:"


@dataclass
class FrameSource:
    """A stream of frames with known length and ground truth; `path` identifies cached odometry."""

    name: str
    gt_poses: np.ndarray
    frames: Callable[[], Iterator[Frame]]
    path: Path | None = None

    def __len__(self) -> int:
        return len(self.gt_poses)


def _live_source(spec: str) -> FrameSource:
    from msa_slam.sim import make_config, prepare

    name, *fields = spec[len(LIVE_PREFIX):].split(",")
    params: dict[str, Any] = {"trajectory": name}
    laps = 1
    for item in fields:
        key, sep, raw = item.partition("=")
        if not sep:
            raise InputError(f"dataset {spec!r}: expected field=value after the name, got {item!r}")
        value = yaml.safe_load(raw)
        if key.strip() == "laps":
            if not isinstance(value, int) or value < 1:
                raise InputError(f"dataset {spec!r}: laps must be an integer >= 1, got {raw!r}")
            laps = value
        else:
            params[key.strip()] = value
    sim = prepare(make_config(**params))
    order = [np.arange(len(sim)) if lap % 2 == 0 else np.arange(len(sim))[::-1] for lap in range(laps)]
    lap_of = np.repeat(np.arange(laps), len(sim))
    index = np.concatenate(order)
    gt = sim.poses[index]
    dt = 1.0 / 10.0 if len(sim.times) < 2 else float(np.median(np.diff(sim.times)))

    def frames() -> Iterator[Frame]:
        for i, (k, lap) in enumerate(zip(index, lap_of)):
            rng = np.random.default_rng([sim.config.seed, int(lap), int(sim.frames[k])])
            points = sim.lidar.scan(sim.poses[k], rng)[:, :3]
            yield Frame(i, i * dt, points, gt[i])

    label = f"live-{name}" + (f"-x{laps}" if laps > 1 else "")
    return FrameSource(label, gt, frames)


def open_source(spec: str, kind: str = "auto", cache_dir: str | os.PathLike | None = None,
                progress: bool = False) -> FrameSource:
    """The frame source named by `spec` (folder, sim:NAME or live:NAME); it must have ground truth."""
    if spec.startswith(LIVE_PREFIX):
        return _live_source(spec)
    sequence = open_sequence(spec, kind, cache_dir, progress)
    return FrameSource(sequence.name, sequence.gt_poses, lambda: iter(sequence), sequence.path)


class NoisyOdometry:
    """Odometry = ground-truth relative motions, each perturbed: step length scaled by 1 + N(0, t_noise),
    rotation by a random small rotation (std `rotation_noise_deg` per axis). Drift grows as a random walk."""

    def __init__(self, gt_poses: np.ndarray, translation_noise: float = 0.01, rotation_noise_deg: float = 0.05,
                 seed: int = 0) -> None:
        if translation_noise < 0 or rotation_noise_deg < 0:
            raise InputError(f"gt-noise odometry: noise must be >= 0, got translation_noise={translation_noise}, "
                             f"rotation_noise_deg={rotation_noise_deg}")
        self._gt = validate_poses(gt_poses, "gt-noise odometry ground truth")
        self.translation_noise = float(translation_noise)
        self.rotation_noise_deg = float(rotation_noise_deg)
        self.seed = int(seed)
        self._rng = np.random.default_rng(self.seed)
        self._pose: np.ndarray | None = None
        self._frames = 0

    @property
    def config(self) -> dict[str, Any]:
        return {"method": "gt_noise", "translation_noise": self.translation_noise,
                "rotation_noise_deg": self.rotation_noise_deg, "seed": self.seed}

    def register(self, points: np.ndarray | None = None, timestamps: np.ndarray | None = None) -> np.ndarray:
        """The next odometry pose (the scan itself is not needed)."""
        i = self._frames
        if i >= len(self._gt):
            raise InputError(f"gt-noise odometry: frame {i} requested but the ground truth has {len(self._gt)}")
        if self._pose is None:
            self._pose = self._gt[0].copy()
        else:
            step = np.linalg.inv(self._gt[i - 1]) @ self._gt[i]
            step[:3, 3] *= 1.0 + self._rng.normal(0.0, self.translation_noise)
            noise = np.eye(4)
            noise[:3, :3] = Rotation.from_rotvec(np.radians(self._rng.normal(0.0, self.rotation_noise_deg, 3))
                                                 ).as_matrix()
            self._pose = self._pose @ step @ noise
        self._frames += 1
        return self._pose.copy()
