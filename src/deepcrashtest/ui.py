"""Terminal output helpers: a stderr console and progress bars that stay out of stdout.

Progress bars are shown only when stderr is a terminal and ``--quiet`` was not given, so
``--json`` output on stdout stays machine-readable and CI logs stay clean.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

T = TypeVar("T")
_QUIET = {"value": False}


def set_quiet(quiet: bool) -> None:
    """Turn progress bars off (``--quiet``)."""
    _QUIET["value"] = quiet


def progress_enabled() -> bool:
    return not _QUIET["value"] and sys.stderr.isatty()


def console_err() -> Console:
    """A rich console writing to stderr (quiet when --quiet)."""
    return Console(stderr=True, quiet=_QUIET["value"])


def track(items: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
    """Iterate ``items`` with a progress bar on stderr when enabled, else plainly."""
    if not progress_enabled():
        yield from items
        return
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, console=Console(stderr=True), transient=True) as progress:
        task = progress.add_task(description, total=total)
        for item in items:
            yield item
            progress.advance(task)
