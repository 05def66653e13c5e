"""The batch front end's two per-frame stages in one pass: a reader thread reads each scan and computes its
descriptor, a few frames ahead into a bounded queue, while the calling thread registers the previous scans.

KISS-ICP's registration (C++) and numpy release the GIL for most of their work, so on two cores reading and
describing the scans hide behind the odometry instead of following it, and each scan is read once instead of
once a stage. A scan's descriptor does not depend on the odometry, and each stage still takes the scans in
order, so the poses, the descriptors and their cache entries are those of the stages run one after the other.
Deskewing stays with the odometry: it needs the motion the previous registration estimated.
"""

from __future__ import annotations

import queue
import threading
from typing import Iterator, Sequence

import numpy as np

from msa_slam.datasets import Frame, ScanSequence
from msa_slam.descriptors import Descriptor
from msa_slam.descriptors.cache import describe, describe_sequence, load_descriptors, save_descriptors
from msa_slam.evaluation import StageTimer
from msa_slam.io.cache import CacheDir, Computed
from msa_slam.odometry import OdometryCache, sequence_odometry
from msa_slam.odometry.cache import Odometry

DEPTH = 4  # frames read ahead: enough to ride out a slow read, a few MB of scans (a 64-beam scan is ~2 MB)
_POLL_S = 0.1  # how often a reader blocked on a full queue checks whether the consumer stopped


class ReadAhead:
    """The frames of `sequence` in order, read (and described by `descriptor`, unless None) by one thread that
    starts when iteration does and stops when it ends, early or not; the reader's errors are raised here, at the
    frame they happened at. After a full iteration `described` holds the descriptors."""

    def __init__(self, sequence: ScanSequence, descriptor: Descriptor | None = None, depth: int = DEPTH) -> None:
        self.sequence, self.descriptor, self.depth = sequence, descriptor, depth
        self._values: list[np.ndarray] = []
        self._ms = np.empty(len(sequence))
        self.complete = False  # every frame was read (and described)

    def __iter__(self) -> Iterator[Frame]:
        frames: queue.Queue = queue.Queue(maxsize=self.depth)
        stop = threading.Event()
        self._values.clear()
        self.complete = False
        reader = threading.Thread(target=self._read, args=(frames, stop), name="msa-slam read-ahead", daemon=True)
        reader.start()
        try:
            for _ in range(len(self.sequence)):
                item = frames.get()
                if isinstance(item, BaseException):
                    raise item
                yield item
            self.complete = True
        finally:
            stop.set()
            reader.join()

    def _read(self, frames: queue.Queue, stop: threading.Event) -> None:
        try:
            for i in range(len(self.sequence)):
                frame = self.sequence[i]
                if self.descriptor is not None:
                    self._values.append(describe(self.descriptor, frame.points, i, self._ms))
                if not _put(frames, frame, stop):
                    return
        except BaseException as exc:  # handed to the consumer, which raises it
            _put(frames, exc, stop)

    def described(self) -> Computed:
        """The descriptors of every frame and the time (ms) computing each took (not from a cache)."""
        if self.descriptor is None or not self.complete:
            raise RuntimeError("ReadAhead.described: no descriptor, or the frames were not all read")
        return Computed(np.stack(self._values), False, self._ms)


def odometry_and_descriptors(sequence: ScanSequence, odometry: Odometry, descriptor: Descriptor, cache: CacheDir,
                             key: str, cache_descriptors: bool = True, pose_file: Sequence[str] = (),
                             quiet: bool = True, timer: StageTimer | None = None) -> tuple[Computed, Computed]:
    """Odometry poses and descriptors (cache key `key`; not cached unless `cache_descriptors`) of every frame of
    `sequence`, each from `cache` when it holds them; when the odometry is computed, the scans are read ahead
    and the missing descriptors computed alongside it (ReadAhead). `pose_file`: the file a pose-file odometry
    reads (part of its key). `timer`'s stages: odometry (that pass, the descriptors computed in it included) and
    descriptors (the time computing them took, hidden in the odometry's when computed alongside)."""
    timer = timer or StageTimer()
    store = cache if cache_descriptors else None
    descriptors = None if store is None else load_descriptors(sequence, descriptor, store, key)
    ahead = ReadAhead(sequence, descriptor if descriptors is None else None)
    label = "odometry" if descriptors is not None else f"odometry and descriptors ({descriptor.name})"
    with timer.stage("odometry"):
        poses = sequence_odometry(sequence, odometry, OdometryCache(cache), quiet, pose_file, ahead, label)
    alongside = descriptors is None and ahead.complete
    with timer.stage("descriptors"):
        if alongside:
            computed = ahead.described()
            descriptors = save_descriptors(store, key, computed.values, computed.ms)
        elif descriptors is None:  # the odometry came from the cache: the scans were not read
            descriptors = save_descriptors(store, key, *describe_sequence(sequence, descriptor, quiet))
    if alongside:
        timer.seconds["descriptors"] += float(descriptors.ms.sum()) / 1e3
    return poses, descriptors


def _put(frames: queue.Queue, item: object, stop: threading.Event) -> bool:
    """Put `item` once the queue has room; False when the consumer stopped first."""
    while not stop.is_set():
        try:
            frames.put(item, timeout=_POLL_S)
            return True
        except queue.Full:
            continue
    return False
