"""The per-frame SLAM core both protocols drive (batch: cached front end, LM at the end; online: live
frames, iSAM2 at every keyframe step).

For each frame: sampler.push (and, with a local-map loop detector, the frame's scan into the local map) -> for
every keyframe it finalises: store its cloud (its local map with such a detector; else the front end's
downsampled cloud of the frame when given, CloudsByFrame, or its scan downsampled here), add it to the pose graph,
look for loop candidates among the older keyframes, store its pose and descriptor, verify the candidates
and add the accepted loops -> update the graph (iSAM2 relinearises; batch LM waits for `finish`).
Every RELEASE_EVERY frames free heap pages go back to the system (iSAM2's piecewise re-elimination leaves them
between long-lived objects); the run's RSS growth is read settled at both ends (evaluation.resources).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any, Protocol, Union

import numpy as np

from msa_slam.descriptors import Descriptor
from msa_slam.errors import InputError
from msa_slam.evaluation import evaluate_trajectories
from msa_slam.evaluation.metrics import JSONValue
from msa_slam.evaluation.resources import current_rss_bytes, release_free_heap, settle_heap
from msa_slam.place_recognition import PRCurve
from msa_slam.registration.cloud_cache import CloudsByFrame
from msa_slam.sampling.base import Sampler
from msa_slam.slam.keyframes import KeyframeStore
from msa_slam.slam.local_map import LocalMap
from msa_slam.slam.loop_closing import LoopCloser
from msa_slam.slam.map import keyframe_map
from msa_slam.slam.result import RunResult, RunSettings
from msa_slam.types import LoopClosure

BACKEND_STEPS = ("sampling", "keyframe_store", "loop_detection", "verification", "graph_update")
Points = Union[np.ndarray, Callable[[], np.ndarray]]  # a scan, or how to read it when it becomes a keyframe
RELEASE_EVERY = 100  # frames between returns of free heap pages (malloc_trim: well under 1 ms each)
MIN_KEYFRAMES = 3  # the evaluation's minimum: its SE(3) alignment of the keyframe trajectories needs 3 poses


class Graph(Protocol):
    """A keyframe pose graph (msa_slam.backend: PoseGraph for batch LM, IncrementalPoseGraph for iSAM2)."""

    @property
    def keys(self) -> list[int]: ...
    @property
    def nbytes(self) -> int: ...
    @property
    def factors(self) -> Any: ...  # gtsam.NonlinearFactorGraph of every factor the optimiser used

    def describe(self) -> Mapping[str, JSONValue]: ...

    def add_keyframe(self, key: int, pose: np.ndarray) -> None: ...
    def add_loop(
        self, target_key: int, source_key: int, T_target_source: np.ndarray, covariance: np.ndarray | None = None
    ) -> None: ...
    def update(self, extra_iterations: int = 0) -> None: ...
    def optimize(self) -> np.ndarray: ...


class Recorder(Protocol):
    """Called after every frame (and after the end-of-stream flush) with the frame's index."""

    def record(self, backend: SlamBackend, frame: int) -> None: ...


def _scan(points: Points) -> np.ndarray:
    return points() if callable(points) else points


class SlamBackend:
    """Frames in, keyframes, loops and a pose graph out: `add_frame` per frame, then `finish()` -> RunResult.
    With a `local_map` every frame's scan is read into it and a keyframe's cloud is its local map; a
    `loop_descriptor` (local-map detector) describes that cloud for loop detection instead of the frame's
    descriptor, which the sampler always uses. Without a local map, `frame_clouds` (every frame's cloud
    downsampled at the store's voxel size) gives a keyframe's cloud without reading its scan."""

    def __init__(
        self,
        settings: RunSettings,
        sampler: Sampler,
        store: KeyframeStore,
        loop_closer: LoopCloser,
        graph: Graph,
        n_frames: int,
        name: str = "sequence",
        update_iterations: int = 0,
        recorder: Recorder | None = None,
        local_map: LocalMap | None = None,
        loop_descriptor: Descriptor | None = None,
        frame_clouds: CloudsByFrame | None = None,
    ) -> None:
        self.settings, self.sampler, self.store = settings, sampler, store
        self.frame_clouds = frame_clouds
        self.local_map, self.loop_descriptor = local_map, loop_descriptor
        self.loop_closer, self.graph = loop_closer, graph
        self.name, self.update_iterations, self.recorder = name, int(update_iterations), recorder
        self.n = int(n_frames)
        self.sampler.expect_frames(self.n, self.settings.flush)
        self.odometry = np.zeros((self.n, 4, 4))
        self.gt = np.full((self.n, 4, 4), np.nan)  # NaN without ground truth: loop distances are then NaN
        self.has_gt: bool | None = None  # decided by the first frame; every frame must agree
        self.times = np.zeros(self.n)
        self.steps_ms = {s: np.zeros(self.n, dtype=np.float32) for s in BACKEND_STEPS}
        self.loops: list[LoopClosure] = []
        self._pending: dict[int, tuple[np.ndarray, Points]] = {}  # frames the sampler may still choose
        self._frames = 0
        self._loop_bytes = 0  # running size of the loop records in `loops`
        # The run's RSS growth is measured from here to `finish`, settled at both ends: what an earlier run in the
        # process freed (or left to the cycle collector) is then counted neither for nor against this one.
        settle_heap()
        self.rss_start = current_rss_bytes()

    @property
    def keyframes(self) -> list[int]:
        return self.graph.keys

    @property
    def oldest_selectable(self) -> int:
        """The oldest frame the sampler may still make a keyframe (the next frame when none may): a front end can
        forget what it holds for older frames."""
        return min(self._pending, default=self._frames)

    @property
    def pending_bytes(self) -> int:
        """Bytes of descriptors and scans buffered for frames the sampler may still choose."""
        return sum(d.nbytes + getattr(p, "nbytes", 0) for d, p in self._pending.values())

    @property
    def record_bytes(self) -> int:
        """Bytes of the run's records so far: per-frame poses, times and step times of the frames seen (their
        arrays are allocated for the whole run, but pages are resident only once written) and loop records."""
        per_frame = (
            (
                self.odometry[0].nbytes
                + self.gt[0].nbytes
                + self.times.itemsize
                + sum(v.itemsize for v in self.steps_ms.values())
            )
            if self.n
            else 0
        )
        return self._frames * per_frame + self._loop_bytes

    def memory_bytes(self) -> dict[str, int]:
        """Accounted bytes now: keyframe clouds (RAM, disk), descriptors, graph, the run's records and (with a
        local-map loop detector) the local map's recent scans."""
        memory = {
            "cloud_bytes": self.store.cloud_bytes,
            "cloud_disk_bytes": self.store.disk_bytes,
            "descriptor_bytes": self.store.descriptor_bytes,
            "graph_bytes": int(self.graph.nbytes),
            "record_bytes": self.record_bytes,
        }
        if self.local_map is not None:
            memory["local_map_bytes"] = self.local_map.nbytes
        return memory

    def add_frame(
        self, odom_pose: np.ndarray, descriptor: np.ndarray, points: Points, gt_pose: np.ndarray | None, time_s: float
    ) -> list[int]:
        """Process the next frame; return the keyframes it finalised (frame indices)."""
        i = self._frames
        if i >= self.n:
            raise InputError(f"SLAM back-end: frame {i} beyond the announced {self.n} frames")
        self._check_gt(i, gt_pose)
        start = time.perf_counter()
        self.odometry[i], self.times[i] = odom_pose, time_s
        if gt_pose is not None:
            self.gt[i] = gt_pose
        sampled_points = _scan(points) if self.sampler.needs_points else None
        if sampled_points is not None:
            points = sampled_points
        self._pending[i] = (descriptor, points)
        sample_pose = self.gt[i] if self.settings.sample_on == "gt" else self.odometry[i]
        new = self.sampler.push(sample_pose, descriptor, sampled_points)
        t = self._timed("sampling", i, start)
        if self.local_map is not None:  # its upkeep is part of keeping keyframes
            self.local_map.add(i, self.odometry[i], _scan(points))
            self._timed("keyframe_store", i, t)
        self._frames += 1
        self._add_keyframes(new, i)
        self._prune()
        if self.local_map is not None:
            self.local_map.forget_before(min(self._pending, default=i))
        if self._frames % RELEASE_EVERY == 0:
            release_free_heap()
        if self.recorder is not None:
            self.recorder.record(self, i)
        return new

    def _check_gt(self, i: int, gt_pose: np.ndarray | None) -> None:
        """A run has ground truth for every frame or for none; the oracle mode needs it."""
        if self.has_gt is None:
            self.has_gt = gt_pose is not None
            if not self.has_gt and self.settings.mode == "oracle":
                raise InputError(
                    "SLAM back-end: the frames have no ground-truth poses, which the oracle mode "
                    "needs (it verifies only loops ground truth confirms); use mode realistic"
                )
            if not self.has_gt and self.settings.sample_on == "gt":
                raise InputError(
                    "SLAM back-end: sample_on=gt but the frames have no ground-truth poses; use sample_on=odometry"
                )
        elif self.has_gt != (gt_pose is not None):
            raise InputError(
                f"SLAM back-end: frame {i} {'lacks' if self.has_gt else 'has'} a ground-truth pose "
                f"but frame 0 {'has' if self.has_gt else 'lacks'} one; give it for all frames or none"
            )

    def _timed(self, step: str, i: int, start: float) -> float:
        now = time.perf_counter()
        self.steps_ms[step][i] += (now - start) * 1e3
        return now

    def _add_keyframes(self, new: list[int], i: int) -> None:
        accepted_any = False
        for k in sorted(int(k) for k in new):
            if k not in self._pending:
                raise RuntimeError(
                    f"sampler {self.settings.sampler!r} chose frame {k} at frame {i}, but frame {k} "
                    "had left its window (keyframes must be window members)"
                )
            keys = self.graph.keys
            if keys and k < keys[-1]:
                raise RuntimeError(
                    f"sampler {self.settings.sampler!r} chose frame {k} after keyframe {keys[-1]} "
                    "(keyframes must come in time order)"
                )
            descriptor, points = self._pending.pop(k)
            t = time.perf_counter()
            if self.local_map is not None:
                self.store.add_cloud(k, self.local_map.around(k))
            elif self.frame_clouds is not None:
                self.store.keep_cloud(k, self.frame_clouds[k])
            else:
                self.store.add_cloud(k, _scan(points))
            self.graph.add_keyframe(k, self.odometry[k])
            t = self._timed("keyframe_store", i, t)
            if self.loop_descriptor is not None:
                descriptor = self.loop_descriptor.compute(self.store.cloud(k), k)
            local = {"cloud": self.store.cloud(k)} if self.settings.loop_detector == "map-closures" else {}
            candidates = self.loop_closer.candidates(k, descriptor, self.gt, self.odometry, **local)
            self.store.add(k, self.odometry[k], descriptor)
            t = self._timed("loop_detection", i, t)
            if candidates:
                verified = self.loop_closer.verify(candidates)
                for loop in verified:
                    if loop.accepted:
                        assert loop.T_match_query is not None, "verification gives an accepted loop its transform"
                        self.graph.add_loop(loop.match, loop.query, loop.T_match_query, loop.covariance)
                        accepted_any = True
                self.loops.extend(verified)
                self._loop_bytes += sum(loop_record_bytes(c) for c in verified)
                self._timed("verification", i, t)
        if new:
            t = time.perf_counter()
            self.graph.update(self.update_iterations if accepted_any else 0)
            self._timed("graph_update", i, t)

    def _prune(self) -> None:
        """Forget buffered frames the sampler can no longer choose, so pending scans stay bounded however
        the robot moves: only members of MSA's window (at most N + 1 frames) may still become keyframes;
        a frame the window skipped (it moved < MIN_WINDOW_STEP, e.g. standing still) never joins it later,
        and samplers without a window decide each frame as it arrives."""
        selectable = set(getattr(self.sampler, "window", ()))
        for f in [f for f in self._pending if f not in selectable]:
            del self._pending[f]

    def finish(self) -> RunResult:
        """Flush the sampler (if configured), optimise the graph and evaluate the keyframe trajectories."""
        n = self._frames
        if n < self.n:  # a shorter stream than announced
            self.odometry, self.gt, self.times = self.odometry[:n], self.gt[:n], self.times[:n]
            self.steps_ms = {k: v[:n] for k, v in self.steps_ms.items()}
        if self.settings.flush and n:
            self._add_keyframes(self.sampler.finish(), n - 1)
            if self.recorder is not None:
                self.recorder.record(self, n - 1)
        keys = np.array(self.graph.keys, dtype=np.int64)
        if len(keys) < MIN_KEYFRAMES:
            flushed = len(self.sampler.flushed_keyframes)
            split = f" ({len(keys) - flushed} online, {flushed} from the end-of-stream flush)" if flushed else ""
            raise InputError(
                f"sampler {self.settings.name!r} kept only {len(keys)} of {n} frames as keyframes"
                f"{split}; the evaluation needs at least {MIN_KEYFRAMES}"
            )
        memory = self.memory_bytes()
        t0 = time.perf_counter()
        optimised = self.graph.optimize()
        self._mark_dropped(getattr(self.graph, "dropped_loops", ()))
        t1 = time.perf_counter()
        gt = self.gt if self.has_gt else None
        pr = self.loop_closer.pr_curve() if gt is not None else no_ground_truth_pr()
        evaluation = evaluate_trajectories(self.odometry[keys], optimised, None if gt is None else gt[keys], keys)
        t2 = time.perf_counter()
        stats = {
            **self.sampler.stats.as_dict(),
            "online_keyframes": len(self.sampler.online_keyframes),
            "flushed_keyframes": len(self.sampler.flushed_keyframes),
        }
        map_points = keyframe_map(self.store.clouds, keys, optimised, self.settings.verifier.voxel_size)
        memory["map_bytes"] = int(map_points.nbytes)
        t3 = time.perf_counter()
        settle_heap()
        rss_growth = current_rss_bytes() - self.rss_start
        return RunResult(
            config=self.settings,
            name=self.name,
            times=self.times,
            odometry=self.odometry,
            gt_poses=gt,
            keyframes=keys,
            optimised=optimised,
            loops=self.loops,
            pr=pr,
            evaluation=evaluation,
            steps_ms=self.steps_ms,
            memory_bytes=memory,
            sampler_stats=stats,
            pr_queries=len(self.loop_closer.best_similarity),
            final_s={"optimisation": t1 - t0, "evaluation": t2 - t1, "map": t3 - t2},
            map_points=map_points,
            graph_factors=self.graph.factors,
            rss_growth_bytes=rss_growth,
            graph_info=self.graph.describe(),
        )

    def _mark_dropped(self, dropped: tuple[int, ...]) -> None:
        """Loops the graph left out as inconsistent (indices in the order they were added, which is the order of
        the accepted records) are recorded as rejected for that reason."""
        if not dropped:
            return
        accepted = [k for k, loop in enumerate(self.loops) if loop.accepted]
        for i in dropped:
            k = accepted[i]
            self.loops[k] = replace(self.loops[k], accepted=False, rejected="inconsistent")

    def close(self) -> None:
        """Release the keyframe clouds (a disk store removes the files it wrote); safe to call twice."""
        self.store.close()


_FLOAT_BYTES = sys.getsizeof(0.0)
_ARRAY_HEADER_BYTES = sys.getsizeof(np.empty(0))


def loop_record_bytes(loop: LoopClosure) -> int:
    """Bytes of one loop record: the object, its attribute dict, its floats, strings and arrays (header plus
    data). Arrays count their data whether they own it or view another's, and every float counts as a
    Python float, and the attribute dict as a plain dict of its keys (an instance dict's own size depends on
    CPython's key sharing, i.e. on which instances the process made before), so the figure depends on the
    loops alone."""
    fields = vars(loop)
    values = 0
    for v in fields.values():
        if isinstance(v, np.ndarray):
            values += _ARRAY_HEADER_BYTES + v.nbytes
        elif isinstance(v, (float, np.floating)):
            values += _FLOAT_BYTES
        elif isinstance(v, str):
            values += sys.getsizeof(v)
    return sys.getsizeof(loop) + sys.getsizeof(dict.fromkeys(fields)) + values


NO_GROUND_TRUTH = "no ground truth: true loops (within loop_radius) cannot be told from false ones"


def no_ground_truth_pr() -> PRCurve:
    """The PR curve of a run without ground truth: empty, with the reason."""
    empty = np.zeros(0)
    return PRCurve(empty, empty, empty, empty, None, None, None, NO_GROUND_TRUTH)
