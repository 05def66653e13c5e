"""What one SLAM run produced (batch or online): trajectories, keyframes, loops, PR curve, timings and its report
(evaluation.metrics.RunMetrics, built by slam.measure), in one layout so tables and reports read either.

A RunResult is immutable: the back end's `finish()` makes one without a report, and a protocol makes the final
one with `dataclasses.replace` (its own records and the report added), never by patching it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Protocol

import numpy as np

from msa_slam.datasets.options import SourceOptions
from msa_slam.evaluation import TrajectoryEvaluation, evaluate_full_rate, full_rate_poses
from msa_slam.evaluation.full_rate import FullRateEvaluation
from msa_slam.evaluation.metrics import JSONValue
from msa_slam.evaluation.run_metrics import RunMetrics
from msa_slam.place_recognition import PRCurve
from msa_slam.registration import VerifierConfig
from msa_slam.sampling.params import SamplerParams
from msa_slam.slam.loop_closing import LoopSettings
from msa_slam.types import LoopClosure


class RunSettings(LoopSettings, Protocol):
    """The fields of a run's configuration the core reads (msa_slam.pipeline.config.RunConfig): the loop-closing
    ones and these, and what its result's readers need to record and describe it (label, odometry, source, dump)."""

    @property
    def dataset(self) -> str: ...
    @property
    def sampler(self) -> str: ...
    @property
    def sampler_params(self) -> SamplerParams: ...
    @property
    def verifier(self) -> VerifierConfig: ...
    @property
    def descriptor(self) -> str: ...
    @property
    def descriptor_params(self) -> dict[str, Any]: ...
    @property
    def sample_on(self) -> str: ...
    @property
    def flush(self) -> bool: ...
    @property
    def local_map_m(self) -> float: ...

    @property
    def name(self) -> str: ...
    @property
    def label(self) -> str | None: ...  # the run's own name, when given
    @property
    def odometry(self) -> str: ...  # "kiss" or a pose file
    @property
    def source(self) -> SourceOptions: ...  # the scans read (first, jump, max_frames)
    def dump(self) -> dict[str, Any]: ...  # the whole configuration, as config.yaml records it


@dataclass(frozen=True)
class RunResult:
    """Everything one run produced. Per-frame arrays cover every frame (`times` are the frames' own);
    `optimised` holds the keyframes' poses; `steps_ms` the back-end's per-frame step times (online adds
    odometry and descriptor) and `memory` online's per-frame memory series."""

    config: RunSettings
    name: str
    times: np.ndarray
    odometry: np.ndarray
    gt_poses: np.ndarray | None  # None without ground truth
    keyframes: np.ndarray
    optimised: np.ndarray
    loops: list[LoopClosure]
    pr: PRCurve | None
    evaluation: TrajectoryEvaluation
    steps_ms: dict[str, np.ndarray]
    memory_bytes: dict[str, int]
    sampler_stats: Mapping[str, JSONValue]  # the sampler's counters (metrics.json `sampler_stats`)
    pr_queries: int  # keyframes that had an older keyframe to query (points of the PR curve)
    final_s: dict[str, float] = field(default_factory=dict)  # optimisation, evaluation and map at the end
    memory: dict[str, np.ndarray] = field(default_factory=dict)
    metrics: RunMetrics | None = None  # the report (slam.measure); None straight out of the back end
    pr_reference: PRCurve | None = None  # the reference example's protocol (batch runs; None: not computed)
    map_points: np.ndarray | None = None  # keyframe clouds at the optimised poses, voxel-merged (world)
    descriptors: np.ndarray | None = None  # per-frame descriptors, when the pipeline kept them (batch)
    graph_factors: Any = None  # the pose graph's factors (gtsam.NonlinearFactorGraph), for pose_graph.g2o
    rss_growth_bytes: int = 0  # process RSS after the final optimisation minus at the back-end's start
    graph_info: Mapping[str, JSONValue] = field(default_factory=dict)  # how loops entered the graph (Graph.describe)

    @property
    def measured(self) -> RunMetrics:
        """The run's report: only a run that pipeline.driver.run measured has one (not the back end's own)."""
        if self.metrics is None:
            raise ValueError(f"{self.name}: the run has no report yet (pipeline.driver.run measures it)")
        return self.metrics

    @property
    def accepted_loops(self) -> list[LoopClosure]:
        return [c for c in self.loops if c.accepted]

    @property
    def backend_ms(self) -> np.ndarray:
        """Per-frame time of everything after odometry (ms)."""
        return sum((v for s, v in self.steps_ms.items() if s != "odometry"), np.zeros(len(self.times)))

    @cached_property
    def optimised_full(self) -> np.ndarray:
        """Every frame's pose after optimisation: its preceding keyframe's optimised pose and the odometry
        between them (evaluation.full_rate)."""
        return full_rate_poses(self.odometry, self.keyframes, self.optimised)

    @cached_property
    def full_rate_evaluation(self) -> FullRateEvaluation:
        """Full-rate ATE/RPE against ground truth (evaluation.full_rate), for the report and the threshold sweep."""
        return evaluate_full_rate(self.odometry, self.optimised_full, self.gt_poses)

    @property
    def ate_errors(self) -> dict[str, np.ndarray | None]:
        return self.evaluation.errors

    def __len__(self) -> int:
        return len(self.odometry)
