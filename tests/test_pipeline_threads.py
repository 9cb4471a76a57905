"""The pipelining helpers of extract: order kept, errors reach the consumer, closing stops the producer."""

from __future__ import annotations

import threading
import time

import pytest

from deepcrashtest.pipeline.threads import Worker, prefetch


def test_prefetch_keeps_order_and_runs_in_another_thread():
    threads = set()

    def produce():
        for k in range(50):
            threads.add(threading.current_thread().name)
            yield k

    assert list(prefetch(produce(), depth=3, name="producer")) == list(range(50))
    assert threads == {"producer"}


def test_prefetch_raises_the_producers_error_after_the_items_before_it():
    def produce():
        yield 1
        yield 2
        raise ValueError("bad frame")

    got = []
    with pytest.raises(ValueError, match="bad frame"):
        for item in prefetch(produce(), depth=1):
            got.append(item)
    assert got == [1, 2]


def test_closing_the_consumer_stops_the_producer():
    produced = []

    def produce():
        for k in range(10_000):
            produced.append(k)
            yield k

    gen = prefetch(produce(), depth=2)
    assert next(gen) == 0
    gen.close()  # joins the producer thread
    n = len(produced)
    time.sleep(0.05)
    assert len(produced) == n < 10  # stopped within the queue depth


def test_worker_runs_items_in_order_and_reports_errors():
    seen = []
    w = Worker(seen.append, depth=2)
    for k in range(20):
        w.submit(k)
    w.close()
    assert seen == list(range(20))

    def fail(item):
        raise RuntimeError(f"encode {item}")

    bad = Worker(fail)
    bad.submit(1)
    with pytest.raises(RuntimeError, match="encode 1"):
        bad.close()
