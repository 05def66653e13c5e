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
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import queue
import traceback
from collections.abc import Callable, Iterable, Iterator
from functools import partial
from multiprocessing.context import ForkContext, SpawnContext
from typing import Any, TypeVar

from msa_slam.errors import InputError
from msa_slam.workers import start_worker

POLL_S = 0.1  # how often a blocked reader checks the consumer stopped, and a waiting consumer that the reader lives
JOIN_S = 5.0  # how long a reader that sent its last item may take to exit before it is killed
T = TypeVar("T")


def forked_ahead(items: Iterable[T], depth: int) -> Iterator[T]:
    """`items` in order, iterated by a forked process that starts when this iteration does, at most `depth` items
    ahead; its errors are raised here, at the item they happened at, and it is gone when this iteration ends,
    early (break, an error, Ctrl-C) or not. `items` must be iterable in a child of this process (files it
    opens itself; no handle or lock shared with the parent) and its items picklable."""
    return _ahead_in(multiprocessing.get_context("fork"), partial(iter, items), depth)


def spawned_ahead(make_items: Callable[[], Iterable[T]], depth: int, niceness: int = 0) -> Iterator[T]:
    """As forked_ahead, the items those of `make_items()` called in a spawned process, `niceness` steps below this
    one's priority: `make_items` must pickle (a module-level function, or a partial of one) and build what it needs
    itself."""
    return _ahead_in(multiprocessing.get_context("spawn"), make_items, depth, niceness)


def _ahead_in(
    context: ForkContext | SpawnContext, make_items: Callable[[], Iterable[T]], depth: int, niceness: int = 0
) -> Iterator[T]:
    """The items of `make_items()`, made by a process `context` starts (at `niceness` below this one's priority)."""
    sent: Any = context.Queue(maxsize=depth)
    stop = context.Event()
    reader = context.Process(
        target=_read, args=(make_items, sent, stop, os.getpid(), niceness), name="msa-slam read-ahead", daemon=True
    )
    reader.start()
    finished = False
    try:
        while True:
            kind, payload = _receive(sent, reader)
            if kind == "end":
                finished = True
                return
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


def _receive(sent: Any, reader: Any) -> tuple[str, Any]:
    """The reader's next message; a RuntimeError when it ended without sending one (killed, out of memory)."""
    while True:
        try:
            return pickle.loads(sent.get(timeout=POLL_S))
        except queue.Empty:
            if reader.is_alive():
                continue
        try:  # its messages are all in the pipe once it has ended
            return pickle.loads(sent.get(timeout=POLL_S))
        except queue.Empty:
            raise RuntimeError(
                f"the front end's reader process ended (exit code {reader.exitcode}) before its last frame"
            ) from None


def _read(make_items: Callable[[], Iterable[Any]], sent: Any, stop: Any, parent: int, niceness: int = 0) -> None:
    """The child: send each item, then the end (or the error that stopped it), until the consumer stops."""
    start_worker(parent)
    try:
        if niceness:
            os.nice(niceness)
        for item in make_items():
            if not _send(sent, ("item", item), stop):
                return
        _send(sent, ("end", None), stop)
    except BaseException as exc:  # handed to the consumer, which raises it
        _send(sent, ("error", _picklable(exc)), stop)


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


def _send(sent: Any, message: tuple[str, Any], stop: Any) -> bool:
    """Put `message` once the queue has room; False when the consumer stopped first (then exit without flushing)."""
    if put_when_room(sent, pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL), stop):
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
