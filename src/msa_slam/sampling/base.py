"""The sampler protocol: frames go in one at a time, finalised keyframe indices come out.

Every sampler (MSA and the paper's baselines) shares this interface so a pipeline can swap them by name:
`push(pose, descriptor, points=None) -> list[int]` returns the frame indices that this frame finalised
as keyframes; `finish()` flushes what is still pending at the end of the stream (reported apart,
because the reference implementation does not flush).

Every sampler also takes the standstill gate (`min_motion`, `min_rotation`, off by default, which is the
reference's behaviour): a frame that moved less than `min_motion` metres from the last frame the gate passed
on, and turned less than `min_rotation` degrees from it, is counted but not passed to the algorithm, so it
is never a keyframe candidate (docs/msa.md, "Standing still"). The SLAM pipelines switch it on.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from msa_slam.errors import InputError
from msa_slam.sampling.params import SamplerParams, check_params
from msa_slam.types import validate_pose


@dataclass(frozen=True)
class AmbiguousWindow:
    """A window optimisation whose choice rounding could change (see sampling/msa/decision.py).

    frame: the frame whose arrival closed the window; members: the frames that were candidates;
    keyframes_before: how many keyframes had been selected before it (they do not depend on it).
    """

    frame: int
    members: tuple[int, ...]
    keyframes_before: int
    margin: float


@dataclass
class SamplerStats:
    """Work counters of a sampler; `optimisation_ms` holds one entry per window optimisation.

    `fallback_windows` counts window optimisations whose distance bounds admitted no candidate, so the
    window's first and last member were taken without a choice (MSA; many of them mean unusable bounds).
    `standstill_frames` counts frames the standstill gate held back (counted in `frames`, never candidates).
    """

    frames: int = 0
    standstill_frames: int = 0
    window_optimisations: int = 0
    candidates_evaluated: int = 0
    fallback_windows: int = 0
    optimisation_ms: list[float] = field(default_factory=list)
    ambiguous: list[AmbiguousWindow] = field(default_factory=list)

    @property
    def ambiguous_windows(self) -> int:
        """Window optimisations whose choice is not reproducible bit for bit on every machine."""
        return len(self.ambiguous)

    def as_dict(self) -> dict:
        times = np.asarray(self.optimisation_ms)
        return {
            "frames": self.frames,
            "standstill_frames": self.standstill_frames,
            "window_optimisations": self.window_optimisations,
            "candidates_evaluated": self.candidates_evaluated,
            "fallback_windows": self.fallback_windows,
            "ambiguous_windows": self.ambiguous_windows,
            "ambiguous_frames": [a.frame for a in self.ambiguous],
            "optimisation_ms_median": float(np.median(times)) if times.size else 0.0,
            "optimisation_ms_p95": float(np.percentile(times, 95)) if times.size else 0.0,
            "optimisation_ms_total": float(times.sum()),
        }


def rotation_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in degrees of the rotation between two poses' orientations (atan2 form: exact near 0 too)."""
    r = a[:3, :3].T @ b[:3, :3]
    sine = 0.5 * float(np.linalg.norm([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]))
    cosine = 0.5 * (float(np.trace(r)) - 1.0)
    return float(np.degrees(np.arctan2(sine, cosine)))


class Sampler(ABC):
    """Base class: validates each frame, numbers it, applies the standstill gate and keeps the keyframe lists.

    The standstill gate (`min_motion` metres, `min_rotation` degrees; `min_motion` 0, the default, is off): a
    frame whose translation from the ANCHOR (the last frame passed on to the algorithm; the first frame always
    is) is below `min_motion` and whose rotation from it is below `min_rotation` (with `min_rotation` 0, any
    rotation) is held back: it keeps its index and is counted in `stats.frames` and `stats.standstill_frames`,
    but the algorithm never sees it, so it can neither be a keyframe nor occupy a window. Measuring from the
    anchor rather than from the previous frame lets slow motion through once it adds up to `min_motion`, and
    a sampler with the gate behaves exactly as the same sampler without it run on the passed frames. It is
    off by default because the reference processes every frame (the parity vectors include frames that moved
    less than a millimetre); the SLAM pipelines switch it on (slam/build.py, STANDSTILL_GATE).
    """

    name: str = "sampler"
    Params: ClassVar[type[SamplerParams]] = SamplerParams
    needs_points: bool = False
    needs_descriptors: bool = False

    def __init__(self, params: SamplerParams | None = None, /, **given: Any) -> None:
        """From parameters a configuration validated (`params`, of this sampler's `Params`), or from keyword
        parameters, validated here (an InputError naming the sampler, the key and what it allows)."""
        if params is None:
            params = check_params(self.Params, given)
        elif given or not isinstance(params, self.Params):
            raise TypeError(f"{self.name}: pass a {self.Params.__name__} or keyword parameters, not both")
        self.params = params
        self.min_motion, self.min_rotation = self.params.min_motion, self.params.min_rotation
        self._anchor: np.ndarray | None = None  # pose of the last frame the standstill gate passed on
        self._online: list[int] = []
        self._flushed: list[int] = []
        self._descriptor_shape: tuple[int, ...] | None = None
        self._finished = False
        self.stats = SamplerStats()

    @property
    def gated(self) -> bool:
        """Whether the standstill gate is on (min_motion > 0)."""
        return self.min_motion > 0

    @property
    def nbytes(self) -> int:
        """Bytes of the data the sampler keeps about the stream (8 per keyframe index and per window
        optimisation's time, the ambiguous-window records, the gate's anchor pose); subclasses add the poses and
        descriptors they buffer. Python's object overhead is not counted."""
        ambiguous = sum(8 * (4 + len(a.members)) for a in self.stats.ambiguous)
        anchor = 0 if self._anchor is None else self._anchor.nbytes
        return 8 * (len(self._online) + len(self._flushed) + len(self.stats.optimisation_ms)) + ambiguous + anchor

    @property
    def keyframes(self) -> list[int]:
        """All keyframes in insertion order: those chosen online, then those from the end-of-stream flush."""
        return self._online + self._flushed

    @property
    def online_keyframes(self) -> list[int]:
        """Keyframes selected while streaming (what the reference implementation reports)."""
        return list(self._online)

    @property
    def flushed_keyframes(self) -> list[int]:
        """Keyframes added by `finish()` only."""
        return list(self._flushed)

    def expect_frames(self, frames: int, flush: bool = False) -> None:
        """Announce the stream's length (and whether finish() will flush) before pushing, so a sampler can warn
        about a useless setting."""

    def push(
        self, pose: np.ndarray, descriptor: np.ndarray | None = None, points: np.ndarray | None = None
    ) -> list[int]:
        """Feed the next frame; return the frame indices this frame finalised as keyframes."""
        if self._finished:
            raise RuntimeError(f"{self.name}: push() after finish()")
        index = self.stats.frames
        pose = validate_pose(pose, where=f"{self.name}: frame {index} pose")
        descriptor = self._check_descriptor(descriptor, index)
        if self.needs_points:
            points = self._check_points(points, index)
        self.stats.frames += 1
        if self._stands_still(pose):
            self.stats.standstill_frames += 1
            return []
        new = self._push(index, pose, descriptor, points)
        self._online.extend(new)
        return new

    def finish(self) -> list[int]:
        """End of stream: return keyframes added by the flush (empty for online baselines)."""
        if self._finished:
            return []
        self._finished = True
        new = self._finish()
        self._flushed.extend(new)
        return new

    def run(
        self, poses: np.ndarray, descriptors: np.ndarray | None = None, clouds=None, flush: bool = False
    ) -> list[int]:
        """Convenience: push a whole stream and return the keyframe list."""
        n = len(poses)
        self.expect_frames(n, flush)
        if descriptors is not None and len(descriptors) != n:
            raise InputError(f"{self.name}: {n} poses but {len(descriptors)} descriptors")
        if clouds is not None and len(clouds) != n:
            raise InputError(f"{self.name}: {n} poses but {len(clouds)} clouds")
        for i in range(n):
            self.push(poses[i], None if descriptors is None else descriptors[i], None if clouds is None else clouds[i])
        if flush:
            self.finish()
        return self.keyframes

    def _stands_still(self, pose: np.ndarray) -> bool:
        """The standstill gate: True holds the frame back; False passes it on and makes it the anchor."""
        if not self.gated:
            return False
        if (
            self._anchor is not None
            and np.linalg.norm(pose[:3, 3] - self._anchor[:3, 3]) < self.min_motion
            and (self.min_rotation == 0 or rotation_deg(self._anchor, pose) < self.min_rotation)
        ):
            return True
        self._anchor = pose.copy()
        return False

    @abstractmethod
    def _push(
        self, index: int, pose: np.ndarray, descriptor: np.ndarray | None, points: np.ndarray | None
    ) -> list[int]:
        """Algorithm step for one validated frame."""

    def _finish(self) -> list[int]:
        return []

    def _check_descriptor(self, descriptor, index: int) -> np.ndarray | None:
        if descriptor is None:
            if self.needs_descriptors:  # before the frame is counted: a caller may catch this and push it again
                raise InputError(f"{self.name}: frame {index} has no descriptor; this sampler needs descriptors")
            return None
        desc = np.asarray(descriptor)
        if desc.dtype.kind not in "biuf":  # complex would lose its imaginary part, text would not convert
            raise InputError(f"{self.name}: frame {index} descriptor must hold real numbers, got dtype {desc.dtype}")
        desc = desc.astype(np.float64, copy=False)
        if desc.ndim not in (1, 2) or desc.size == 0:
            raise InputError(
                f"{self.name}: frame {index} descriptor must be a non-empty 1-D or 2-D array, got shape {desc.shape}"
            )
        if self._descriptor_shape is None:
            self._descriptor_shape = desc.shape
        elif desc.shape != self._descriptor_shape:
            raise InputError(
                f"{self.name}: frame {index} descriptor has shape {desc.shape}, "
                f"earlier frames had {self._descriptor_shape}"
            )
        if not np.isfinite(desc).all():
            raise InputError(f"{self.name}: frame {index} descriptor has NaN or infinite values")
        return desc

    def _check_points(self, points, index: int) -> np.ndarray:
        if points is None:
            raise InputError(f"{self.name}: frame {index} has no point cloud; this sampler needs points")
        pts = np.asarray(points)
        if pts.ndim != 2 or pts.shape[1] < 3 or pts.shape[0] == 0:
            raise InputError(f"{self.name}: frame {index} points must be (P, 3) with P > 0, got {pts.shape}")
        pts = pts[:, :3]
        if not np.isfinite(pts).all():
            raise InputError(f"{self.name}: frame {index} points contain NaN or infinite values")
        return pts


class Timer:
    """Wall-clock milliseconds of a block (perf_counter)."""

    def __enter__(self) -> Timer:
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        self.ms = (time.perf_counter() - self._t0) * 1e3
