"""Forked: a function's result from a forked child, the same as computed here; failures raised here."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from deepcrashtest.forking import Forked


def _pid_and_sum(a: np.ndarray) -> tuple[int, float]:
    return os.getpid(), float(a.sum())


def _fails(message: str) -> None:
    raise ValueError(message)


def _single_threaded() -> bool:
    return hasattr(os, "fork") and threading.active_count() == 1


def test_result_comes_from_a_child_and_equals_the_function():
    a = np.arange(200_000, dtype=float)  # larger than a pipe's buffer once pickled
    job = Forked(_pid_and_sum, a)
    pid, total = job.result()
    assert total == float(a.sum())
    if not _single_threaded():
        pytest.skip("other threads run in this test process: no fork (by design)")
    assert job.in_child and pid != os.getpid()


def test_a_failing_child_raises_here_with_the_functions_own_error():
    job = Forked(_fails, "bad input")
    with pytest.raises(ValueError, match="bad input"):
        job.result()


def test_no_fork_while_other_python_threads_run():
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        job = Forked(_pid_and_sum, np.ones(3))
        assert not job.in_child
        assert job.result() == (os.getpid(), 3.0)
    finally:
        stop.set()
        other.join()
