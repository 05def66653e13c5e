"""A run's report as typed, immutable objects: what was run, loops, trajectory error (keyframes and full rate),
place recognition, memory, time and throughput, batch and online alike.

A value that is undefined for the run (ATE without ground truth, PR-AUC without revisits) is an
`Unavailable` carrying its reason, never a bare None, so that every reader (tables, report.md) can say why.
evaluation.run_metrics.RunMetrics holds the sections of one run; evaluation.metrics_writer writes metrics.json from
it (the keys and bytes metrics.json always had) and evaluation.metrics_json reads it back for `msa-slam report`,
compare's reuse of finished seeds and experiment cells. ProtocolRecord: what a protocol (batch, online) measured
around the SLAM core, which slam.measure joins with the core's own metrics.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeVar, Union

if TYPE_CHECKING:
    import numpy as np

T = TypeVar("T")
BATCH = "batch"
ONLINE = "online"


@dataclass(frozen=True)
class Unavailable:
    """A metric that is undefined for this run, and why (metrics.json: null, with the reason in `unavailable`)."""

    reason: str


Value = Union[int, float, Unavailable]
JSONValue = Union[None, bool, int, float, str, list, Mapping]  # free-form records (sampler counters, configs)


def known(value: T | Unavailable) -> T | None:
    """The value, or None when unavailable: what a table cell or a CSV column holds."""
    return None if isinstance(value, Unavailable) else value


def reason_of(value: Value | None) -> str | None:
    """Why `value` is unavailable (None when it is a number)."""
    return value.reason if isinstance(value, Unavailable) else None


@dataclass(frozen=True)
class RunIdentity:
    """What was run: the sequence, the labels of dataset, method, sampler and descriptor, and the sizes."""

    sequence: str
    dataset: str
    method: str
    sampler: str
    descriptor: str
    mode: str
    frames: int
    keyframes: int


@dataclass(frozen=True)
class KeyframeErrors:
    """ATE/RPE of one keyframe trajectory against ground truth (RMSE; RPE between consecutive keyframes)."""

    ate_translation_m: Value
    ate_rotation_deg: Value
    rpe_translation_m: Value
    rpe_rotation_deg: Value


@dataclass(frozen=True)
class FullRateErrors:
    """ATE and distance RPE of one trajectory at every frame (KITTI segments, and 10 m all pairs)."""

    ate_translation_m: Value
    ate_rotation_deg: Value
    rpe_kitti_translation_pct: Value
    rpe_kitti_rotation_deg_per_100m: Value
    rpe_10m_translation_m: Value
    rpe_10m_rotation_deg: Value


@dataclass(frozen=True)
class Improvement:
    """The paper's % ATE improvement, 100 (before - after) / before."""

    translation: Value
    rotation: Value


@dataclass(frozen=True)
class KeyframeTrajectory:
    """Odometry (`before`) and optimised (`after`) keyframe trajectories against ground truth."""

    before: KeyframeErrors
    after: KeyframeErrors
    improvement: Improvement
    alignment: str | Unavailable
    rotation_reliable: bool | Unavailable


@dataclass(frozen=True)
class FullRateTrajectory:
    """The same comparison on every frame (a keyframe's optimised pose and the odometry since)."""

    before: FullRateErrors
    after: FullRateErrors
    improvement: Improvement
    frames: int
    alignment: str | Unavailable


@dataclass(frozen=True)
class LoopClosing:
    """How loops were closed: rejections per reason and the graph's account (`details`, in metrics.json order)."""

    rejected: Mapping[str, int]
    details: Mapping[str, JSONValue]


@dataclass(frozen=True)
class LoopCounts:
    """Where the revisits were lost (evaluation.loops.account_loops, each value or why it is undefined)."""

    candidates: int
    registered: int
    accepted: int
    rejected: Mapping[str, int]
    true_candidates: Value
    false_loops: Value
    distant_loops: Value
    revisits: Value
    revisits_closed: Value
    revisit_recall: Value
    revisit_keyframes: Value
    revisit_keyframes_closed: Value
    revisit_keyframe_recall: Value


@dataclass(frozen=True)
class Loops:
    """Loop candidates, verified and false loops, and their accounting against ground truth."""

    candidates: int
    true_candidates: Value
    verified: int
    registrations: int
    closing: LoopClosing
    accounting: LoopCounts

    @property
    def false_loops(self) -> Value:
        """Accepted loops whose measured pose is false (evaluation.loops: one count, kept in the accounting)."""
        return self.accounting.false_loops

    @property
    def rejected(self) -> int:
        """Registered candidates rejected, every reason together."""
        return sum(self.accounting.rejected.values())


@dataclass(frozen=True)
class ReferencePR:
    """PR-AUC / F1-max of the reference example's place-recognition protocol (batch runs)."""

    pr_auc: Value
    f1_max: Value
    matches: int


@dataclass(frozen=True)
class SweepRow:
    """One similarity threshold of the batch threshold sweep (false loops as evaluation.loops counts them; full-rate
    ATE after and its improvement)."""

    threshold: float
    candidates: int
    loops_accepted: int
    false_loops: int
    ate_after_m: Value
    improvement_t_pct: Value


@dataclass(frozen=True)
class PlaceRecognition:
    """PR-AUC / F1-max of the run's loop candidates; batch adds the reference protocol and the threshold sweep
    (Unavailable for online runs, and for a sweep that did not run)."""

    pr_auc: Value
    f1_max: Value
    queries: int
    reference: ReferencePR | Unavailable
    sweep: tuple[SweepRow, ...] | Unavailable


@dataclass(frozen=True)
class AccountedMemory:
    """Accounted bytes at the end of the run (docs/metrics.md, "Memory"); `local_map` only with a local-map loop
    detector, `clouds_on_disk` and `cloud_store` only online (None: not part of this run's record)."""

    keyframe_descriptors: int
    keyframe_clouds: int
    graph: int
    local_map: int | None
    total: int
    run_records: int
    map: int
    in_ram: int
    clouds_on_disk: int | None = None
    cloud_store: str | None = None


@dataclass(frozen=True)
class Memory:
    """Accounted memory and the process's resident-set figures (those differ between two runs)."""

    accounted: AccountedMemory
    peak_rss_bytes: int
    peak_rss_scope: str
    rss_growth_bytes: int
    rss_growth_ratio: Value

    @property
    def total_mib(self) -> float:
        return self.accounted.total / 2**20

    @property
    def rss_growth_mib(self) -> float:
        return self.rss_growth_bytes / 2**20

    def bytes_per_keyframe(self, keyframes: int) -> float:
        return self.accounted.total / keyframes


@dataclass(frozen=True)
class Timing:
    """Seconds per back-end stage (`stages`, metrics.json time_s: None for a stage that did not run) and, batch,
    the front end's and the sampler's share of real time."""

    stages: Mapping[str, float | None]
    replayed_s: Mapping[str, float]
    frontend_s: Mapping[str, float] | None = None
    frontend_cached: Mapping[str, bool] | None = None
    sampler_realtime_fraction: Value | None = None

    @property
    def backend_total(self) -> float:
        total = self.stages["backend_total"]
        if total is None:  # only a stage that did not run is None, and the back end always runs
            raise ValueError("time_s.backend_total is null: every run records its back end's time")
        return total


def sampler_realtime_fraction(
    sampler_stats: Mapping[str, JSONValue], times: np.ndarray, times_known: bool
) -> float | Unavailable:
    """Timing's `sampler_realtime_fraction`: the sampler's window optimisations' total time over the duration of the
    data it sampled (the frames' first to last timestamp), the share of a real-time budget sampling alone takes.
    Unavailable, with why, when the frames have no timestamps (`times_known` False: their times are frame numbers,
    1 frame/s) or span no time."""
    if not times_known:
        return Unavailable("the frames have no timestamps, so the data's duration is unknown")
    span = float(times[-1] - times[0]) if len(times) > 1 else 0.0
    if not span > 0:
        return Unavailable("the frames' timestamps span no time")
    total_ms = sampler_stats["optimisation_ms_total"]
    assert isinstance(total_ms, (int, float)), "the sampler's statistics count milliseconds as numbers"
    return total_ms / 1e3 / span


@dataclass(frozen=True)
class Latency:
    """Per-frame time percentiles of one step (ms)."""

    p50: float
    p95: float
    p99: float
    max: float


@dataclass(frozen=True)
class Throughput:
    """How fast an online run went: frames per second of the pipeline and of the back end, against the data's rate,
    and per-step latency."""

    pipeline_time_s: float
    fps: float
    backend_fps: float
    frame_rate_hz: float
    frame_rate_from: str
    realtime_factor: float
    latency_ms: Mapping[str, Latency]
    odometry_cached: bool


@dataclass(frozen=True)
class Deskew:
    """Whether KISS-ICP deskewed the scans (None: another odometry) and why."""

    on: bool | None
    why: str


@dataclass(frozen=True)
class RunSetup:
    """Settings and diagnostics: the odometry's effective config (batch), deskew, threads."""

    deskew: Deskew
    threads: Mapping[str, int | None]
    odometry_config: Mapping[str, JSONValue] | None = None

    @property
    def odometry_threads(self) -> int | None:
        return self.threads.get("odometry")


NOT_BATCH = "online runs have no reference protocol and no threshold sweep (batch-only analyses)"
NOTHING_IN_RAM = "nothing accounted in RAM to compare the RSS growth with"
_NOT_BATCH = Unavailable(NOT_BATCH)


@dataclass(frozen=True)
class ProtocolRecord:
    """What a protocol measured around the core: its warnings (listed before the core's), stage times, settings,
    the reasons it adds to `unavailable` (after the core's) and, batch, the reference PR and the threshold sweep,
    online, the throughput and the cloud store; `peak_rss_bytes`: the process's peak when the run ended, read before
    analyses that are no part of it (batch: the sweep; None: read now)."""

    pipeline: str
    warnings: tuple[str, ...]
    timing: Timing
    setup: RunSetup
    reasons: Mapping[str, str] = field(default_factory=dict)
    reference: ReferencePR | Unavailable = _NOT_BATCH
    sweep: tuple[SweepRow, ...] | Unavailable = _NOT_BATCH
    throughput: Throughput | None = None
    cloud_store: str | None = None
    peak_rss_bytes: int | None = None
