"""Forked and Helper: results from a forked child, the same as computed here; failures raised here."""

from __future__ import annotations

import os
import signal
import threading

import numpy as np
import pytest

from deepcrashtest.forking import Forked, Helper


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


def test_helper_runs_its_jobs_in_order_in_one_child():
    a = np.arange(200_000, dtype=float)
    with Helper() as helper:
        helper.submit(_pid_and_sum, a)
        helper.submit(_pid_and_sum, a[:10])
        (pid1, s1), (pid2, s2) = helper.results()
    assert (s1, s2) == (float(a.sum()), float(a[:10].sum()))
    if not _single_threaded():
        pytest.skip("other threads run in this test process: no fork (by design)")
    assert pid1 == pid2 != os.getpid()


def test_helper_raises_a_jobs_error_here():
    with Helper() as helper:
        helper.submit(_fails, "bad table")
        with pytest.raises(ValueError, match="bad table"):
            helper.results()


def test_a_killed_helper_is_not_trusted_its_jobs_run_here():
    with Helper() as helper:
        if helper._proc is not None:
            os.kill(helper._proc.pid, signal.SIGKILL)
            helper._proc.join()
        helper.submit(_pid_and_sum, np.ones(4))
        assert helper.results() == [(os.getpid(), 4.0)]
