"""Pipelining helpers: run a stage of the one-pass extraction in its own thread.

Decoding (PyAV), the detector (onnxruntime / OpenCV DNN), optical flow and H.264 encoding release
the GIL while they work, so a stage per thread keeps both cores of a small machine busy. Queues are
bounded (frames are large); an exception in a stage reaches the consumer; closing the consumer's
iterator (``break``, an error) stops the producer thread.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Generator, Iterable
from typing import Generic, TypeVar

T = TypeVar("T")
_END = object()


class _Failure:
    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


def prefetch(items: Iterable[T], depth: int = 4, name: str = "stage") -> Generator[T, None, None]:
    """Iterate ``items`` in a background thread, ``depth`` items ahead of the caller."""
    q: queue.Queue[object] = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()

    def put(item: object) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for item in items:
                if not put(item):
                    return
            put(_END)
        except BaseException as exc:  # handed to the consumer, raised there
            put(_Failure(exc))

    thread = threading.Thread(target=produce, name=name, daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is _END:
                return
            if isinstance(item, _Failure):
                raise item.exc
            yield item  # type: ignore[misc]
    finally:
        stop.set()
        thread.join()


class Worker(Generic[T]):
    """Calls ``fn(item)`` for each :meth:`submit` ted item, in order, in one background thread.

    :meth:`close` waits for the queue to drain and raises the first error of ``fn``; ``submit``
    raises it as soon as it is known.
    """

    def __init__(self, fn: Callable[[T], None], depth: int = 4, name: str = "worker") -> None:
        self._fn = fn
        self._q: queue.Queue[object] = queue.Queue(maxsize=max(1, depth))
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is _END:
                return
            if self._error is None:
                try:
                    self._fn(item)  # type: ignore[arg-type]
                except BaseException as exc:  # kept and raised in the submitting thread
                    self._error = exc

    def submit(self, item: T) -> None:
        if self._error is not None:
            raise self._error
        self._q.put(item)

    def close(self) -> None:
        self._q.put(_END)
        self._thread.join()
        if self._error is not None:
            raise self._error
