"""Terminal output helpers: a stderr console and progress bars that stay out of stdout.

Progress bars are shown only when stderr is a terminal and neither ``--quiet`` nor ``--json`` was
given (the CLI calls :func:`set_quiet` for both), so machine-readable output and CI logs stay clean.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:  # rich is imported where a console or a bar is made (~40 ms of every command's start-up)
    from rich.console import Console

T = TypeVar("T")
_QUIET = {"value": False}


def set_quiet(quiet: bool) -> None:
    """Turn progress bars off (``--quiet``)."""
    _QUIET["value"] = quiet


def progress_enabled() -> bool:
    return not _QUIET["value"] and sys.stderr.isatty()


def console_err() -> Console:
    """A rich console writing to stderr (quiet when --quiet)."""
    from rich.console import Console

    return Console(stderr=True, quiet=_QUIET["value"])


def track(items: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
    """Iterate ``items`` with a progress bar on stderr when enabled, else plainly."""
    with progress_bar(description, total) as advance:
        for item in items:
            yield item
            advance(1)


@contextlib.contextmanager
def progress_bar(description: str, total: float | None) -> Iterator[Callable[[float], None]]:
    """A progress bar with a time estimate on stderr (when enabled); yields ``advance(n)``."""
    if not progress_enabled():
        yield lambda _n: None
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, console=Console(stderr=True), transient=True) as progress:
        task = progress.add_task(description, total=total)
        yield lambda n: progress.advance(task, n)


@contextlib.contextmanager
def status(message: str) -> Iterator[None]:
    """A spinner with ``message`` and the time elapsed on stderr (when enabled) while a step of no known length
    runs (stage 2 after extract's frames: half a minute on a 200 s recording)."""
    if not progress_enabled():
        yield
        return
    from rich.console import Console
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    columns = (SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn())
    with Progress(*columns, console=Console(stderr=True), transient=True) as progress:
        progress.add_task(message, total=None)
        yield
