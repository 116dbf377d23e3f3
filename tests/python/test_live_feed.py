"""The live feed's sender never waits on the queue (bench._live.LiveFeed): it sleeps until a
batch is due and takes what is there, so a ``put`` from a thread that talks to the drive
never has a waiter to wake (waking the sender on every item made puts slow under CPU load;
the stalls are measured by benchmarks/bench_live.py, not asserted here). The data still all
arrives, in order, and close() sends what was queued."""

from __future__ import annotations

import queue
from typing import Any

import numpy as np

from bench._live import LiveFeed


class SpyQueue:
    """A SimpleQueue that records how it was read."""

    def __init__(self) -> None:
        self.q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.blocking_gets = 0
        self.nowait_gets = 0

    def put(self, item: Any) -> None:
        self.q.put(item)

    def qsize(self) -> int:
        return self.q.qsize()

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        self.blocking_gets += 1
        return self.q.get(block, timeout)

    def get_nowait(self) -> Any:
        self.nowait_gets += 1
        return self.q.get_nowait()


class Recorder:
    """A transport double: what the feed sent."""

    def __init__(self) -> None:
        self.rows: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        self.batches = 0

    def send(self, entity: str, t: np.ndarray, v: np.ndarray) -> None:
        self.rows.setdefault(entity, []).append((t.copy(), v.copy()))

    def end_batch(self) -> None:
        self.batches += 1


def test_sender_never_waits_on_the_queue_and_sends_everything_in_order() -> None:
    feed = LiveFeed(None, rate_hz=0, batch_s=0.005)
    spy = SpyQueue()
    feed._q = spy  # type: ignore[assignment]  # before anything is queued or attached
    rec = Recorder()
    feed.attach(rec)
    t_all = np.arange(3000) * 1e-3
    for k in range(300):
        t = t_all[10 * k:10 * k + 10]
        assert feed.put("tel.", t, {"i_q_A": 2.0 * t})
    stats = feed.close()
    assert spy.blocking_gets == 0 and spy.nowait_gets > 0
    assert stats.items_in == 300 and stats.items_dropped == 0 and stats.items_unsent == 0
    t_sent = np.concatenate([t for t, _ in rec.rows["current/i_q"]])
    v_sent = np.concatenate([v for _, v in rec.rows["current/i_q"]])
    np.testing.assert_array_equal(t_sent, t_all)  # every sample, in order (rate 0: all)
    np.testing.assert_array_equal(v_sent, 2.0 * t_all)
    assert rec.batches == stats.batches >= 1
