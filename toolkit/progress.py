"""Progress bars for long work: on a terminal only, silent in pipes, tests and CI."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import TypeVar

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TaskProgressColumn,
    TextColumn,
    TimeRemainingColumn,
)

T = TypeVar("T")


def enabled() -> bool:
    return sys.stderr.isatty() and not os.environ.get("TOOLKIT_NO_PROGRESS")


def bar() -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TaskProgressColumn(),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        transient=True,
        disable=not enabled(),
    )


def track(items: Iterable[T], description: str, total: float | None = None) -> Iterator[T]:
    """Iterate with a progress bar on stderr (when it is a terminal)."""
    with bar() as progress:
        yield from progress.track(items, total=total, description=description)


@contextmanager
def task(description: str, total: float) -> Iterator[tuple[Progress, TaskID]]:
    """A bar advanced by hand: `with task("import", n) as (p, k): p.advance(k, m)`."""
    with bar() as progress:
        yield progress, progress.add_task(description, total=total)
