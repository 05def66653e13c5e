"""Items iterated ahead by another process, forked from this one or spawned, so that the work of making them runs
on another core.

A thread is not enough when the consumer's own work holds the GIL: KISS-ICP's Python binding does not release it
while it registers a scan (a pure-Python thread makes ~5 % of its progress while register_frame runs), so a reader
thread's reading, describing and downsampling would run one after the other with the odometry, not beside it.
The forked process starts with the parent's objects (the sequence, the descriptor) in its memory: nothing is
pickled but the items it sends back, each pickled in the child so that a failure to pickle is one of its errors.
It ends with its parent (lifetime.end_with_parent) and leaves Ctrl-C to it, as compare's workers do (workers.py).
A spawned process (spawned_ahead) starts from a fresh interpreter instead: for items whose making uses a library
that may hold threads in this process (the simulator's ray casting), which a fork would copy in an unknown state.

A forked reader hands the items' large buffers (a scan's points and times, its downsampled cloud) over through a
ring of shared memory slots mapped before the fork (Slots), so that only a small header goes through the pipe:
a 2 MB scan through the pipe costs the consumer, whose time is the odometry's, several copies and a wake-up every
64 kB. The slots are anonymous shared mappings, inherited by the child and never named, so no path (an error,
Ctrl-C, either process killed) can leave one behind: they are freed when both processes have let go of them.
"""

from __future__ import annotations

import mmap
import multiprocessing
import os
import pickle
import queue
import traceback
from collections.abc import Callable, Generator, Iterable, Iterator
from functools import partial
from multiprocessing.context import ForkContext, SpawnContext
from typing import Any, Generic, TypeVar

from msa_slam.errors import InputError
from msa_slam.workers import start_worker

POLL_S = 0.1  # how often a blocked reader checks the consumer stopped, and a waiting consumer that the reader lives
JOIN_S = 5.0  # how long a reader that sent its last item may take to exit before it is killed
# Bytes of out-of-band buffers one item may hand over through shared memory (a larger one goes through the pipe):
# a 128-beam scan with its times and cloud is ~10 MB. Only the pages an item writes are backed by memory.
SLOT_BYTES = 32 << 20
T = TypeVar("T")
R = TypeVar("R")


def forked_ahead(items: Iterable[T], depth: int) -> Iterator[T]:
    """`items` in order, iterated by a forked process that starts when this iteration does, at most `depth` items
    ahead; its errors are raised here, at the item they happened at, and it is gone when this iteration ends,
    early (break, an error, Ctrl-C) or not. `items` must be iterable in a child of this process (files it
    opens itself; no handle or lock shared with the parent) and its items picklable."""
    context = multiprocessing.get_context("fork")
    return _ahead_in(context, partial(_emit_all, partial(iter, items)), depth, partial(_slots, context, depth))


def spawned_ahead(make_items: Callable[[], Iterable[T]], depth: int) -> Iterator[T]:
    """As forked_ahead, the items those of `make_items()` called in a spawned process: `make_items` must pickle
    (a module-level function, or a partial of one) and build what it needs itself. Its items come through the
    pipe whole (a spawned child does not inherit mappings)."""
    return _ahead_in(multiprocessing.get_context("spawn"), partial(_emit_all, make_items), depth, lambda: None)


class ForkedProducer(Generic[T, R]):
    """`produce(emit)` run in a forked process that may have children of its own (not daemonic): the items it
    passes to `emit`, in order, at most `depth` ahead of the consumer, then what it returns (`result`). For work
    whose producer itself wants a reader process beside it (the batch front end's odometry: pipeline.streamed).
    `start()` forks it (iteration starts it too); it is gone once iteration ends or `close()` is called, as a
    forked_ahead reader is, and its errors are raised where its items are received. Its buffers go through
    slots of `slot_bytes`."""

    def __init__(self, produce: Callable[[Callable[[T], None]], R], depth: int, slot_bytes: int = SLOT_BYTES) -> None:
        self._context = multiprocessing.get_context("fork")
        self._produce, self._depth, self._slot_bytes = produce, depth, slot_bytes
        self._items: Generator[T, None, R] | None = None
        self.result: R | None = None

    def start(self) -> None:
        if self._items is None:
            slots = partial(_slots, self._context, self._depth, self._slot_bytes)
            self._items = _ahead_in(self._context, self._produce, self._depth, slots, daemon=False)
            self._items = _started(self._items)

    def __iter__(self) -> Generator[T, None, None]:
        self.start()
        assert self._items is not None
        self.result = yield from self._items

    def close(self) -> None:
        """Stop the producer (what it was producing is not needed); safe to call twice or before `start`."""
        if self._items is not None:
            self._items.close()


def _started(items: Generator[T, None, Any]) -> Generator[T, None, Any]:
    """`items` with its process started now: _ahead_in's first step forks it and yields a None marker."""
    marker = next(items)
    assert marker is None, "_ahead_in yields None once its process has started"
    return items


class _Stopped(Exception):
    """Raised in a producer's process by `emit` when the consumer stopped: unwinds the producer."""


def _emit_all(make_items: Callable[[], Iterable[T]], emit: Callable[[T], None]) -> None:
    for item in make_items():
        emit(item)


class Slots:
    """A ring of shared memory slots, one item's out-of-band buffers each, mapped before the fork so that the
    child inherits them: the child takes a free slot (in order), writes the buffers and sends their sizes; the
    consumer copies them out and frees the slot. Items are received in the order they are sent, so slots are
    freed in the order they are taken. `depth` + 2 slots: `depth` items queued, one being copied out, one being
    written."""

    def __init__(self, context: ForkContext, depth: int, slot_bytes: int | None = None) -> None:
        self.slot_bytes = SLOT_BYTES if slot_bytes is None else slot_bytes
        self.maps = [mmap.mmap(-1, self.slot_bytes) for _ in range(depth + 2)]  # anonymous, shared with children
        self.free = context.Semaphore(len(self.maps))
        self.taken = 0  # slots the child took (in the child)

    def put(self, buffers: list[pickle.PickleBuffer], stop: Any) -> tuple[int, tuple[int, ...]] | None:
        """(the slot `buffers` were written to, their sizes), once a slot is free; None when they do not fit in one
        or the consumer stopped first (`stop` set): then they go through the pipe."""
        raws = [buffer.raw() for buffer in buffers]
        if sum(raw.nbytes for raw in raws) > self.slot_bytes:
            return None
        while not self.free.acquire(timeout=POLL_S):
            if stop.is_set():
                return None
        slot = self.taken % len(self.maps)
        self.taken += 1
        start = 0
        with memoryview(self.maps[slot]) as view:
            for raw in raws:
                view[start : start + raw.nbytes] = raw
                start += raw.nbytes
        return slot, tuple(raw.nbytes for raw in raws)

    def take(self, slot: int, sizes: tuple[int, ...]) -> list[bytearray]:
        """Copies of the buffers in `slot` (`sizes` bytes each); the slot is free again."""
        copies, start = [], 0
        with memoryview(self.maps[slot]) as view:
            for size in sizes:
                copies.append(bytearray(view[start : start + size]))
                start += size
        self.free.release()
        return copies

    def close(self) -> None:
        for mapped in self.maps:
            mapped.close()


def _slots(context: ForkContext, depth: int, slot_bytes: int | None = None) -> Slots | None:
    """Slots for `depth` items ahead; None (every item through the pipe) when the system will not map them (a
    strict overcommit limit)."""
    try:
        return Slots(context, depth, slot_bytes)
    except OSError:
        return None


def _ahead_in(
    context: ForkContext | SpawnContext,
    produce: Callable[[Callable[[Any], None]], Any],
    depth: int,
    make_slots: Callable[[], Slots | None],
    daemon: bool = True,
) -> Generator[Any, None, Any]:
    """The items `produce(emit)` emits, made by a process `context` starts, their buffers in the slots `make_slots`
    maps (none: all through the pipe); returns what `produce` returned. A non-daemonic process (`daemon` False)
    yields None first, once started (ForkedProducer.start)."""
    sent: Any = context.Queue(maxsize=depth)
    stop = context.Event()
    slots = make_slots()
    try:
        reader = context.Process(
            target=_read, args=(produce, sent, stop, os.getpid(), slots), name="msa-slam read-ahead", daemon=daemon
        )
        reader.start()
    except BaseException:
        if slots is not None:
            slots.close()
        raise
    finished = False
    try:
        if not daemon:
            yield None
        while True:
            kind, payload = _receive(sent, reader, slots)
            if kind == "end":
                finished = True
                return payload
            if kind == "error":
                raise payload
            yield payload
    finally:
        stop.set()
        reader.join(JOIN_S if finished else 0.0)
        if reader.is_alive():
            reader.kill()  # stopped early: what it was reading is not needed
            reader.join()
        sent.close()
        reader.close()
        if slots is not None:
            slots.close()


def _receive(sent: Any, reader: Any, slots: Slots | None) -> tuple[str, Any]:
    """The reader's next message; a RuntimeError when it ended without sending one (killed, out of memory)."""
    while True:
        try:
            return _unpacked(sent.get(timeout=POLL_S), slots)
        except queue.Empty:
            if reader.is_alive():
                continue
        try:  # its messages are all in the pipe once it has ended
            return _unpacked(sent.get(timeout=POLL_S), slots)
        except queue.Empty:
            raise RuntimeError(
                f"the front end's reader process ended (exit code {reader.exitcode}) before its last frame"
            ) from None


def _unpacked(packed: tuple[bytes, int | None, tuple[int, ...]], slots: Slots | None) -> tuple[str, Any]:
    """A message from what _send put on the queue: (its pickle, the slot holding its out-of-band buffers or None,
    their sizes)."""
    header, slot, sizes = packed
    if slot is None:
        return pickle.loads(header)
    assert slots is not None, "a message in a slot needs the slots"
    return pickle.loads(header, buffers=slots.take(slot, sizes))


def _read(
    produce: Callable[[Callable[[Any], None]], Any], sent: Any, stop: Any, parent: int, slots: Slots | None
) -> None:
    """The child: send each item `produce` emits, then the end with what it returned (or the error that stopped
    it), until the consumer stops."""
    start_worker(parent)

    def emit(item: Any) -> None:
        if not _send(sent, ("item", item), stop, slots):
            raise _Stopped

    try:
        result = produce(emit)
        _send(sent, ("end", result), stop, slots)
    except _Stopped:
        return
    except BaseException as exc:  # handed to the consumer, which raises it
        _send(sent, ("error", _picklable(exc)), stop, slots)


def put_when_room(target: Any, item: object, stop: Any) -> bool:
    """Put `item` on `target` (a thread's or a process's queue) once it has room; False when the consumer stopped
    first (`stop` set)."""
    while not stop.is_set():
        try:
            target.put(item, timeout=POLL_S)
            return True
        except queue.Full:
            continue
    return False


def _send(sent: Any, message: tuple[str, Any], stop: Any, slots: Slots | None) -> bool:
    """Put `message` once the queue has room, its out-of-band buffers (arrays) in a slot when there are slots and
    they fit in one; False when the consumer stopped first (then exit without flushing)."""
    packed: tuple[bytes, int | None, tuple[int, ...]] | None = None
    if slots is not None:
        buffers: list[pickle.PickleBuffer] = []
        header = pickle.dumps(message, protocol=5, buffer_callback=buffers.append)
        placed = slots.put(buffers, stop) if buffers else None
        if placed is not None or not buffers:
            packed = (header, None, ()) if placed is None else (header, *placed)
        elif stop.is_set():
            sent.cancel_join_thread()
            return False
    if packed is None:
        packed = (pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL), None, ())
    if put_when_room(sent, packed, stop):
        return True
    sent.cancel_join_thread()
    return False


def _picklable(exc: BaseException) -> BaseException:
    """`exc` (a bug's with the child's traceback as a note; bad input's message names what is wrong), or a
    RuntimeError saying what it was when it does not pickle."""
    where = "in the front end's reader process:\n" + "".join(traceback.format_exception(exc)).rstrip()
    try:
        add_note = getattr(exc, "add_note", None)  # Python 3.11 and later
        if add_note is not None and not isinstance(exc, InputError):
            add_note(where)
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}\n{where}")
