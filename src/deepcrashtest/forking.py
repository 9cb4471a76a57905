"""Run a Python-bound function in a forked child process while this process does other work.

Matplotlib holds the GIL while it draws, so threads cannot draw two figures at once; a forked child
can (it shares the parent's memory copy-on-write: no pickling of the arguments, no imports). The
result comes back pickled through a pipe. Where ``fork`` is not available, or other Python threads
are running (a thread holding an import lock or a logging lock at the fork would leave that lock held
for ever in the child), the function runs in this process instead, when the result is asked for.
"""

from __future__ import annotations

import os
import pickle
import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar

T = TypeVar("T")


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity where the system has one), at least 1."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


class Forked(Generic[T]):
    """``fn(*args)`` started in a forked child now; :meth:`result` waits for it (or computes it here).

    A child that fails (an exception, killed) is not trusted: :meth:`result` then calls ``fn`` in this
    process, so an error is raised here with its own traceback, and the result never depends on where
    it was computed.
    """

    def __init__(self, fn: Callable[..., T], *args: Any) -> None:
        self._fn, self._args = fn, args
        self._pid: int | None = None
        self._read = -1
        self._forked = False
        if hasattr(os, "fork") and threading.active_count() == 1:
            self._start()

    def _start(self) -> None:
        read, write = os.pipe()
        pid = os.fork()
        if pid == 0:  # the child: compute, send, leave without running the parent's exit handlers
            code = 1
            try:
                os.close(read)
                data = pickle.dumps(self._fn(*self._args), protocol=pickle.HIGHEST_PROTOCOL)
                with os.fdopen(write, "wb") as out:
                    out.write(data)
                code = 0
            finally:
                os._exit(code)
        os.close(write)
        self._pid, self._read, self._forked = pid, read, True

    @property
    def in_child(self) -> bool:
        """Whether a child process was started to compute the result."""
        return self._forked

    def result(self) -> T:
        """The function's result (waits for the child; computes it here where no child ran or it failed)."""
        if self._pid is None:
            return self._fn(*self._args)
        with os.fdopen(self._read, "rb") as pipe:
            data = pipe.read()  # before waiting: a result larger than the pipe's buffer blocks the child
        _, status = os.waitpid(self._pid, 0)
        self._pid = None
        if status != 0 or not data:
            return self._fn(*self._args)
        return pickle.loads(data)  # noqa: S301 - our own child's bytes


class Helper:
    """A forked child process that runs the functions handed to it, in order, while this process goes on.

    Fork it early, before this process imports what it alone needs: the child shares what is imported so far
    and loads what its jobs need (``preload``, e.g. OpenCV) on the other core meanwhile. :meth:`submit` hands it
    ``fn(*args)`` (``fn`` a module-level function, pickled by name: its module must be light to import; the
    arguments pickled), :meth:`results` waits for every job's result, in order, and raises the first job's
    error. Where ``fork`` is not available, or other threads run, or the child dies, the jobs run here, in
    :meth:`results`.
    """

    def __init__(self, preload: Callable[[], Any] | None = None) -> None:
        self._jobs: list[tuple[Callable[..., Any], tuple[Any, ...]]] = []
        self._conn: Any = None
        self._proc: Any = None
        if hasattr(os, "fork") and threading.active_count() == 1:
            import multiprocessing

            ctx = multiprocessing.get_context("fork")
            self._conn, child = ctx.Pipe()
            self._proc = ctx.Process(target=_helper_main, args=(child, preload), daemon=True)
            self._proc.start()
            child.close()

    def submit(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` in the child (here, in :meth:`results`, without one)."""
        self._jobs.append((fn, args))
        if self._proc is not None:
            try:
                self._conn.send((fn, args))
            except OSError:  # the child died: every job runs here, in results()
                self.close()

    def results(self) -> list[Any]:
        """Every submitted job's result, in order (waits for them); the first failure is raised here."""
        jobs, self._jobs = self._jobs, []
        if self._proc is None:
            return [fn(*args) for fn, args in jobs]
        try:
            replies = [self._conn.recv() for _ in jobs]
        except (EOFError, OSError):  # the child died (killed): not trusted, every job runs here
            self.close()
            return [fn(*args) for fn, args in jobs]
        for ok, value in replies:
            if not ok:
                raise value
        return [value for _, value in replies]

    def close(self) -> None:
        """Stop the child now (jobs not collected by :meth:`results` are dropped; an early error does not wait for
        its ``preload``)."""
        if self._proc is not None:
            if self._proc.is_alive():
                self._proc.terminate()
            self._proc.join()
            self._conn.close()
            self._proc = None

    def __enter__(self) -> Helper:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _helper_main(conn: Any, preload: Callable[[], Any] | None) -> None:
    if preload is not None:
        preload()
    while (job := conn.recv()) is not None:
        fn, args = job
        try:
            conn.send((True, fn(*args)))
        except Exception as exc:  # handed to the parent, which raises it
            conn.send((False, exc))
