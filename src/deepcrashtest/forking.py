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
