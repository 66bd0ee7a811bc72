"""The reader's queue (ptinertia.stage_threads.HandOffQueue): a blocked producer is woken
once the consumer has taken half, and nothing is lost, reordered or left waiting."""

from __future__ import annotations

import queue
import threading

import pytest

from ptinertia.stage_threads import HandOffQueue


def _wakes(q: queue.Queue[int], monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Fill ``q`` to its bound, then take every item: the queue sizes at which a get went
    on to wake a waiting producer (threading.Condition.notify called through)."""
    for i in range(q.maxsize):
        q.put(i)
    woke: list[int] = []
    notify = threading.Condition.notify

    def counted(self: threading.Condition, n: int = 1) -> None:
        woke.append(q._qsize())  # (the queue's lock is held here)
        notify(self, n)

    monkeypatch.setattr(threading.Condition, "notify", counted)
    taken = [q.get() for _ in range(q.maxsize)]
    assert taken == list(range(q.maxsize))
    return woke


def test_a_get_wakes_the_producer_only_once_half_is_taken(monkeypatch) -> None:
    assert _wakes(HandOffQueue(8), monkeypatch) == [4, 3, 2, 1, 0]
    assert _wakes(HandOffQueue(1), monkeypatch) == [0]
    # (queue.Queue wakes it after every get: the cost this queue saves)
    assert _wakes(queue.Queue(8), monkeypatch) == [7, 6, 5, 4, 3, 2, 1, 0]


def test_a_wake_for_all_wakes_a_full_queue_s_producers(monkeypatch) -> None:
    """notify_all (a shutdown's) is not held back until half is taken."""
    q = HandOffQueue(4)
    for i in range(4):
        q.put(i)
    called: list[int] = []
    notify = threading.Condition.notify

    def counted(self: threading.Condition, n: int = 1) -> None:
        called.append(n)
        notify(self, n)

    monkeypatch.setattr(threading.Condition, "notify", counted)
    with q.mutex:
        q.not_full.notify()  # full: held back
        q.not_full.notify_all()
    assert called == [0]  # notify_all passed on (to no waiter: n = 0)


def test_a_producer_ahead_of_its_consumer_hands_over_every_item_in_order() -> None:
    q = HandOffQueue(4)
    n = 2000

    def produce() -> None:
        for i in range(n):
            q.put(i)  # blocks while full, until the consumer has taken half
        q.put(-1)

    producer = threading.Thread(target=produce, daemon=True)
    producer.start()
    got = []
    while (item := q.get(timeout=10.0)) != -1:  # (a lost wake: queue.Empty, not a hang)
        got.append(item)
    producer.join(timeout=10.0)
    assert got == list(range(n)) and not producer.is_alive()


def test_an_unbounded_queue_and_a_timed_get_behave_as_the_standard_one() -> None:
    q = HandOffQueue()
    for i in range(100):
        q.put_nowait(i)
    assert [q.get(timeout=1.0) for _ in range(100)] == list(range(100))
    with pytest.raises(queue.Empty):
        q.get(timeout=0.0)
    with pytest.raises(queue.Empty):
        q.get_nowait()
