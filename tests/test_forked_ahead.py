"""A forked reader hands its items' arrays over through shared memory slots mapped before the fork: they arrive
whole, in order and writable, whatever their size (too large for a slot: through the pipe), and no slot outlives
the iteration, however it ends (the last item, a break, Ctrl-C, the reader's error, the reader killed)."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
from collections.abc import Iterator
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from msa_slam.pipeline import forked_ahead as forked
from msa_slam.pipeline.forked_ahead import forked_ahead

MAPS = Path("/proc/self/maps")


def _item(i: int) -> dict[str, np.ndarray | int]:
    """A frame-like item: a 2 MB scan, its per-point times, a strided view (not contiguous: pickled in the header,
    kept small so that the header is written to the pipe at once: a reader killed while it writes a longer one
    would leave the consumer waiting for the rest), a number."""
    rng = np.random.default_rng(i)
    points = rng.normal(size=(80_000, 3))
    return {"index": i, "points": points, "times": rng.random(80_000).astype(np.float32), "xs": points[:700:7, 0]}


def _items(n: int, fail_at: int | None = None, kill_at: int | None = None) -> Iterator[dict]:
    for i in range(n):
        if i == fail_at:
            raise ValueError(f"item {i}: unreadable")
        if i == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)
        yield _item(i)


def _slot_mappings() -> int:
    """This process's shared anonymous mappings the size of a slot (an anonymous shared mapping shows as
    /dev/zero in /proc/self/maps)."""
    count = 0
    for line in MAPS.read_text().splitlines():
        span, *_, name = line.split(maxsplit=5)
        start, end = (int(x, 16) for x in span.split("-"))
        count += "/dev/zero" in name and end - start == forked.SLOT_BYTES
    return count


@pytest.mark.parametrize("fit", [True, False], ids=["slots", "too-large-for-a-slot"])
def test_items_arrive_whole_in_order_and_writable(monkeypatch, fit):
    if not fit:
        monkeypatch.setattr(forked, "SLOT_BYTES", 1 << 20)
    taken = []
    take = forked.Slots.take
    monkeypatch.setattr(forked.Slots, "take", lambda self, *a: taken.append(a[0]) or take(self, *a))
    received = list(forked_ahead(_items(12), depth=2))
    assert [item["index"] for item in received] == list(range(12))
    for item in received:
        expected = _item(item["index"])
        for name in ("points", "times", "xs"):
            assert item[name].dtype == expected[name].dtype and np.array_equal(item[name], expected[name])
            assert item[name].flags.writeable
    # in a slot when they fit (4 slots for a depth of 2, taken in turn), else through the pipe
    assert taken == ([i % 4 for i in range(12)] if fit else [])
    assert not multiprocessing.active_children()


@pytest.mark.skipif(not MAPS.exists(), reason="needs /proc/self/maps")
@pytest.mark.parametrize("end", ["last item", "break", "Ctrl-C", "reader's error", "reader killed"])
def test_no_slot_outlives_the_iteration(end):
    before = _slot_mappings()
    items = _items(40, fail_at=5 if end == "reader's error" else None, kill_at=5 if end == "reader killed" else None)
    seen = []
    with contextlib.suppress(KeyboardInterrupt, ValueError, RuntimeError):
        for item in forked_ahead(items, depth=2):
            assert _slot_mappings() == before + 4  # mapped while the reader runs
            seen.append(item["index"])
            if item["index"] == 3 and end in ("break", "Ctrl-C"):
                if end == "Ctrl-C":
                    raise KeyboardInterrupt
                break
    assert seen == (list(range(40)) if end == "last item" else list(range(len(seen))))
    assert len(seen) == {"last item": 40, "break": 4, "Ctrl-C": 4, "reader's error": 5}.get(end, len(seen))
    assert _slot_mappings() == before and not multiprocessing.active_children()


def test_items_come_through_the_pipe_when_slots_cannot_be_mapped(monkeypatch):
    def refused(*args):
        raise OSError(12, "Cannot allocate memory")

    monkeypatch.setattr(forked.mmap, "mmap", refused)
    received = list(forked_ahead(_items(6), depth=2))
    assert [item["index"] for item in received] == list(range(6))
    assert np.array_equal(received[5]["points"], _item(5)["points"]) and not multiprocessing.active_children()


def _produce_with_a_reader(n: int, emit) -> str:
    """A producer that reads its items through a forked reader of its own (as the streamed front end's pass
    does), emits them and returns a summary."""
    for item in forked_ahead(_items(n), depth=2):
        emit(item["index"])
    return f"{n} emitted"


def _produce_then_fail(emit) -> None:
    emit(0)
    raise ValueError("frame 1: corrupt scan")


def test_a_producer_with_its_own_reader_hands_on_its_items_and_result():
    producer = forked.ForkedProducer(partial(_produce_with_a_reader, 7), depth=3)
    assert list(producer) == list(range(7)) and producer.result == "7 emitted"
    assert not multiprocessing.active_children()


def test_a_producers_error_is_raised_where_its_items_are_received():
    received = []
    with pytest.raises(ValueError, match="frame 1: corrupt scan"):
        received.extend(forked.ForkedProducer(_produce_then_fail, depth=2))
    assert received == [0] and not multiprocessing.active_children()


def test_a_producer_closed_early_is_gone():
    producer = forked.ForkedProducer(partial(_produce_with_a_reader, 40), depth=2)
    producer.start()
    items = iter(producer)
    assert next(items) == 0
    producer.close()
    assert producer.result is None and not multiprocessing.active_children()
    forked.ForkedProducer(partial(_produce_with_a_reader, 3), depth=2).close()  # never started: nothing to stop
