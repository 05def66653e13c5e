"""The batch front end's per-frame stages in one pass: a reader reads each scan, computes its descriptor and its
downsampled cloud (the keyframe store's form, registration.cloud_cache), a few frames ahead into a bounded queue,
while the calling thread registers the previous scans.

The reader is a process forked for the pass (pipeline.forked_ahead) when the sequence reads each scan from its own
file (ScanSequence.forkable) and this process may have children, else a thread. A thread overlaps little: KISS-ICP's Python binding holds the GIL
while it registers a scan, so the reader's Python work waits for each registration to end. In a process, reading,
describing and downsampling run on another core, and each scan is read and parsed once a run instead of once a
stage. A scan's descriptor and cloud do not depend on the odometry, and each stage still takes the scans in order,
so the poses, descriptors, clouds and their cache entries are those of the stages run one after the other.
Deskewing stays with the odometry: it needs the motion the previous registration estimated.
"""

from __future__ import annotations

import multiprocessing
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from msa_slam.datasets import Frame, ScanSequence
from msa_slam.descriptors import Descriptor
from msa_slam.descriptors.cache import describe, load_descriptors, save_descriptors
from msa_slam.evaluation import StageTimer
from msa_slam.io.cache import CacheDir, Computed
from msa_slam.odometry import OdometryCache, sequence_odometry
from msa_slam.odometry.cache import Odometry
from msa_slam.pipeline.forked_ahead import forked_ahead, put_when_room
from msa_slam.progress import progress_bar
from msa_slam.registration.cloud_cache import ComputedClouds, load_frame_clouds, save_frame_clouds
from msa_slam.registration.clouds import downsample

DEPTH = 4  # frames read ahead: enough to ride out a slow read, a few MB of scans (a 64-beam scan is ~2 MB)
_END = object()  # put by the reader after the last item
T = TypeVar("T")


class ReadAhead:
    """The frames of `sequence` in order, read (described by `descriptor` and downsampled at `voxel_size`, unless
    None) by one process (a forkable sequence) or thread that starts when iteration does and stops when it ends,
    early or not; the reader's errors are raised here, at the frame they happened at. After a full iteration
    `described` holds the descriptors and `downsampled` the clouds."""

    def __init__(
        self,
        sequence: ScanSequence,
        descriptor: Descriptor | None = None,
        depth: int = DEPTH,
        voxel_size: float | None = None,
    ) -> None:
        self.sequence, self.descriptor, self.depth, self.voxel_size = sequence, descriptor, depth, voxel_size
        self._values: list[np.ndarray] = []
        self._ms = np.empty(len(sequence))
        self._clouds: list[np.ndarray] = []
        self._cloud_ms = np.empty(len(sequence))
        self.complete = False  # every frame was read (described and downsampled)

    @property
    def computes(self) -> bool:
        """Whether the reader computes anything besides reading (a pass is worth making for it alone)."""
        return self.descriptor is not None or self.voxel_size is not None

    def __iter__(self) -> Iterator[Frame]:
        self._values.clear()
        self._clouds.clear()
        self.complete = False
        # a daemonic process (a Dask worker running an experiment's cell) may not have children
        forkable = getattr(self.sequence, "forkable", False) and not multiprocessing.current_process().daemon
        parsed = getattr(self.sequence, "parsed", None)
        if forkable and parsed is not None:  # where the child keeps the text scans it parses, for this process
            parsed.prepare(self.sequence.scan_files)
        read = forked_ahead if forkable else ahead
        for i, (frame, described, downsampled) in enumerate(read(self._computed(), self.depth)):
            if described is not None:
                self._values.append(described[0])
                self._ms[i] = described[1]
            if downsampled is not None:
                self._clouds.append(downsampled[0])
                self._cloud_ms[i] = downsampled[1]
            yield frame
        self.complete = True

    def _computed(self) -> Iterator[tuple[Frame, tuple[np.ndarray, float] | None, tuple[np.ndarray, float] | None]]:
        """Each frame read, with its (descriptor, ms computing it) and (downsampled cloud, ms), None when not asked
        for (run by the reader: in a forked process, what it computes reaches this one only with the frame)."""
        for i in range(len(self.sequence)):
            frame = self.sequence[i]
            value = cloud = None
            if self.descriptor is not None:
                value = describe(self.descriptor, frame.points, i, self._ms), float(self._ms[i])
            if self.voxel_size is not None:
                start = time.perf_counter()
                cloud = (
                    downsample(frame.points, self.voxel_size, where=f"frame {i}"),
                    (time.perf_counter() - start) * 1e3,
                )
            yield frame, value, cloud

    def outputs(self, i: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Frame `i`'s descriptor and downsampled cloud (None when not asked for), once frame `i` was yielded."""
        return (
            self._values[i] if self.descriptor is not None else None,
            self._clouds[i] if self.voxel_size is not None else None,
        )

    def described(self) -> Computed:
        """The descriptors of every frame and the time (ms) computing each took (not from a cache)."""
        if self.descriptor is None or not self.complete:
            raise RuntimeError("ReadAhead.described: no descriptor, or the frames were not all read")
        return Computed(np.stack(self._values), False, self._ms)

    def downsampled(self) -> tuple[list[np.ndarray], np.ndarray]:
        """(every frame's downsampled cloud, the time (ms) downsampling each took)."""
        if self.voxel_size is None or not self.complete:
            raise RuntimeError("ReadAhead.downsampled: no voxel size, or the frames were not all read")
        return self._clouds, self._cloud_ms


@dataclass(frozen=True)
class FrontEndStages:
    """The cached front end's stages of every frame, each computed or read from the cache (`cached`) with the time
    computing it took (`ms`); `clouds` None for the local-map loop detectors, which store local maps instead."""

    odometry: Computed
    descriptors: Computed
    clouds: ComputedClouds | None

    def by_name(self) -> dict[str, Computed | ComputedClouds]:
        """The stages present, by name, in the order the report lists them."""
        named = {"odometry": self.odometry, "descriptors": self.descriptors, "clouds": self.clouds}
        return {name: stage for name, stage in named.items() if stage is not None}


def frontend_pass(
    sequence: ScanSequence,
    odometry: Odometry,
    descriptor: Descriptor,
    cache: CacheDir,
    key: str,
    cache_descriptors: bool = True,
    pose_file: Sequence[str] = (),
    quiet: bool = True,
    timer: StageTimer | None = None,
    clouds: tuple[float, str] | None = None,
    on_frame: FrameHook | None = None,
) -> FrontEndStages:
    """The stages `odometry`, `descriptors` (cache key `key`; not cached unless `cache_descriptors`) and, when
    `clouds` is (voxel size, cache key), `clouds` (every frame downsampled: registration.cloud_cache) of every
    frame of `sequence`, each from `cache` when it holds it. The missing ones are computed in one pass over the
    scans (ReadAhead): alongside the odometry when it is computed, else in a pass that only reads. `pose_file`:
    the file a pose-file odometry reads (part of its key). `timer`'s stages: odometry (its pass, what was computed
    alongside included), descriptors and clouds (the time computing them took, hidden in the odometry's when
    computed alongside). `on_frame(i, pose, descriptor, cloud)` gets every frame in order, as soon as its pose is
    computed (all at the end when the odometry is replayed): a back end beside the pass (pipeline.streamed)."""
    timer = timer or StageTimer()
    store = cache if cache_descriptors else None
    descriptors = None if store is None else load_descriptors(sequence, descriptor, store, key)
    frame_clouds = None if clouds is None else load_frame_clouds(sequence, clouds[0], cache, clouds[1])
    ahead = ReadAhead(
        sequence,
        descriptor if descriptors is None else None,
        voxel_size=clouds[0] if clouds is not None and frame_clouds is None else None,
    )
    label = "odometry" + "".join(
        f" and {what}"
        for what, todo in (
            (f"descriptors ({descriptor.name})", descriptors is None),
            ("clouds", ahead.voxel_size is not None),
        )
        if todo
    )
    handover = None if on_frame is None else _Handover(on_frame, ahead, descriptors, frame_clouds)
    with timer.stage("odometry"):
        poses = sequence_odometry(
            sequence,
            odometry,
            OdometryCache(cache),
            quiet,
            pose_file,
            ahead,
            label,
            None if handover is None else handover.pose,
        )
    if ahead.computes and not ahead.complete:  # the odometry came from the cache: the scans were not read
        _read_through(ahead, quiet, label.removeprefix("odometry and "))
    if descriptors is None:
        computed = ahead.described()
        descriptors = save_descriptors(store, key, computed.values, computed.ms)
    if clouds is not None and frame_clouds is None:
        frame_clouds = save_frame_clouds(*ahead.downsampled(), clouds[0], cache, clouds[1])
    stages = FrontEndStages(poses, descriptors, frame_clouds)
    if handover is not None:
        handover.rest(stages)
    for name, stage in stages.by_name().items():  # computed by the reader: the time it took
        if name != "odometry" and not stage.cached:
            timer.seconds[name] = timer.seconds.get(name, 0.0) + float(stage.ms.sum()) / 1e3
    return stages


# A frame handed on as the pass completes it: (index, odometry pose, descriptor, downsampled cloud or None)
FrameHook = Callable[[int, np.ndarray, np.ndarray, "np.ndarray | None"], None]


class _Handover:
    """Each frame to `on_frame` in order, as its pose is computed (descriptor and cloud from the cache or the
    reader), the frames not handed on yet once the stages are complete (`rest`: a replayed odometry)."""

    def __init__(
        self, on_frame: FrameHook, ahead: ReadAhead, descriptors: Computed | None, clouds: ComputedClouds | None
    ) -> None:
        self.on_frame, self.ahead, self.descriptors, self.clouds = on_frame, ahead, descriptors, clouds
        self.handed = 0

    def pose(self, i: int, pose: np.ndarray) -> None:
        described, cloud = self.ahead.outputs(i)
        descriptor = self.descriptors.values[i] if self.descriptors is not None else described
        if self.clouds is not None:
            cloud = self.clouds.values[i]
        assert descriptor is not None, "the reader describes the frames when the cache has no descriptors"
        self.on_frame(i, pose, descriptor, cloud)
        self.handed = i + 1

    def rest(self, stages: FrontEndStages) -> None:
        clouds = stages.clouds
        for i in range(self.handed, len(stages.odometry.values)):
            cloud = None if clouds is None else clouds.values[i]
            self.on_frame(i, stages.odometry.values[i], stages.descriptors.values[i], cloud)
        self.handed = len(stages.odometry.values)


def _read_through(ahead: ReadAhead, quiet: bool, label: str) -> None:
    """Iterate `ahead` to its end for what its reader computes, with a progress bar named `label`."""
    with progress_bar(quiet) as bar:
        task = bar.add_task(label, total=len(ahead.sequence))
        for _ in ahead:
            bar.advance(task)


def ahead(items: Iterable[T], depth: int = DEPTH) -> Iterator[T]:
    """`items` in order, iterated by a thread of their own that starts when this iteration does, at most `depth`
    items ahead (a short live run's frames simulated while the previous ones are registered: pipeline.live); the
    thread's errors are raised here, at the item they happened at, and it stops when this iteration ends, early
    or not."""
    queued: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    reader = threading.Thread(target=_read, args=(iter(items), queued, stop), name="msa-slam read-ahead", daemon=True)
    reader.start()
    try:
        while (item := queued.get()) is not _END:
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        reader.join()


def _read(items: Iterator[Any], queued: queue.Queue, stop: threading.Event) -> None:
    try:
        for item in items:
            if not put_when_room(queued, item, stop):
                return
        put_when_room(queued, _END, stop)
    except BaseException as exc:  # handed to the consumer, which raises it
        put_when_room(queued, exc, stop)
