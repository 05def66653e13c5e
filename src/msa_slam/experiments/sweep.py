"""Sensitivity to the similarity threshold: loops accepted and full-rate ATE improvement of one
batch run at thresholds around its own (SWEEP_OFFSETS: 0.70, 0.75, 0.80, 0.85 around the paper's 0.8).

Only the back-end is re-run: the same keyframes (a replay sampler emits the run's keyframes), the same
downsampled keyframe clouds (shared, not re-read) and the cached front end, streamed through the same SLAM
core (`build_backend`, a new one per threshold) with the threshold changed. A candidate pair's verification does
not depend on the threshold, so each pair is registered once over the whole sweep (the run's own pairs are reused).
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import Any

import numpy as np

from msa_slam.backend import PoseGraph
from msa_slam.evaluation.loops import count_false_loops
from msa_slam.evaluation.metrics import SweepRow
from msa_slam.pipeline.config import RunConfig, make_config
from msa_slam.pipeline.frontend import CachedFrontEnd
from msa_slam.sampling.base import Sampler
from msa_slam.slam import LoopCloser, RunResult, build_backend, build_loop_closer
from msa_slam.types import LoopClosure

SWEEP_OFFSETS = (-0.10, -0.05, 0.0, 0.05)


def sweep_thresholds(threshold: float) -> list[float]:
    """The thresholds of the sweep around `threshold`, within [0, 1]."""
    return sorted({round(min(1.0, max(0.0, threshold + d)), 6) for d in SWEEP_OFFSETS})


class _ReplaySampler(Sampler):
    """Emits the given keyframes, each as its frame arrives."""

    name = "replay"

    def __init__(self, keyframes: np.ndarray) -> None:
        super().__init__()
        self._keys = {int(k) for k in keyframes}

    def _push(
        self, index: int, pose: np.ndarray, descriptor: np.ndarray | None, points: np.ndarray | None
    ) -> list[int]:
        return [index] if index in self._keys else []


class _SharedClouds:
    """The run's downsampled keyframe clouds: storing one again keeps the stored cloud (no scan is read)."""

    def __init__(self, clouds: Any) -> None:
        self._clouds = clouds

    def add(self, key: int, points: np.ndarray) -> np.ndarray:
        return self._clouds[key]

    def keep(self, key: int, cloud: np.ndarray) -> np.ndarray:
        return self._clouds[key]

    def __getitem__(self, key: int) -> np.ndarray:
        return self._clouds[key]

    @property
    def nbytes(self) -> int:
        return 0


class _MemoVerify(LoopCloser):
    """`closer`'s loop closing, with verification outcomes shared by pair (query, match) across the sweep."""

    def __init__(self, closer: LoopCloser, memo: dict[tuple[int, int], LoopClosure]) -> None:
        super().__init__(closer.store, closer.verifier, closer.settings, closer.map_closures)
        self._memo = memo

    def verify(self, candidates: list[LoopClosure]) -> list[LoopClosure]:
        new = [c for c in candidates if (c.query, c.match) not in self._memo]
        for c in super().verify(new) if new else []:
            self._memo[(c.query, c.match)] = c
        return [self._memo[(c.query, c.match)] for c in candidates]


def replay(
    config: RunConfig,
    frontend: CachedFrontEnd,
    clouds: Any,
    keyframes: np.ndarray,
    memo: dict[tuple[int, int], LoopClosure],
) -> RunResult:
    """The back-end of `config` on fixed `keyframes` whose clouds are in `clouds` (front end from `frontend`)."""
    closer = _MemoVerify(build_loop_closer(config, frontend.descriptor, _SharedClouds(clouds)), memo)
    backend = build_backend(
        config,
        _ReplaySampler(keyframes),
        closer,
        PoseGraph(config.graph, mode=config.mode),
        len(frontend),
        frontend.name,
        local_maps=False,
    )  # local maps: among the shared clouds
    times, gt, shared = frontend.sequence.times, frontend.gt_poses, _SharedClouds(clouds)
    for i in range(len(frontend)):
        # a keyframe's cloud is the run's (the replay's sampler keeps the run's keyframes): no scan is read
        cloud = partial(shared.__getitem__, i)
        backend.add_frame(frontend.odometry[i], frontend.descriptors[i], cloud, None if gt is None else gt[i], times[i])
    return backend.finish()


def _row(threshold: float, result: RunResult) -> SweepRow:
    trajectory = result.full_rate_evaluation.trajectory
    if result.gt_poses is None:
        raise ValueError(f"{result.name}: the threshold sweep needs ground truth to count false loops")
    return SweepRow(
        threshold,
        len(result.loops),
        len(result.accepted_loops),
        count_false_loops(result.loops, result.gt_poses, result.config.loop_radius),
        trajectory.after.ate_translation_m,
        trajectory.improvement.translation,
    )


def threshold_sweep(result: RunResult, frontend: CachedFrontEnd, clouds: Any) -> tuple[SweepRow, ...]:
    """One row per threshold of the sweep (candidates, loops accepted, false loops, full-rate ATE after and
    % improvement); the run's own threshold is the run itself, the others are replays."""
    config = result.config
    # verification outcomes only: a loop the run's graph left out as inconsistent passed verification, and the
    # replay's graph decides again on its own set of loops
    memo = {
        (c.query, c.match): replace(c, accepted=True, rejected="") if c.rejected == "inconsistent" else c
        for c in result.loops
    }
    rows = []
    for threshold in sweep_thresholds(config.similarity_threshold):
        if threshold == round(config.similarity_threshold, 6):
            rows.append(_row(threshold, result))
            continue
        swept = make_config({**config.dump(), "similarity_threshold": threshold})
        rows.append(_row(threshold, replay(swept, frontend, clouds, result.keyframes, memo)))
    return tuple(rows)
