"""Progress bars for long work: on a terminal only, silent in pipes, tests and CI."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable, Iterator
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


@contextmanager
def counted(
    description: str, total: float, unit: str, steps: str, n_steps: int
) -> Iterator[tuple[Callable[[float], None], Callable[[], None]]]:
    """Two bars: `total` `unit` counted as the work goes, and `n_steps` fixed `steps` (e.g.
    the outputs), so that the count does not sit at 100% while the steps run. Yields
    (advance the count by m, advance the steps by one)."""
    with bar() as progress:
        work = progress.add_task(f"{description}: {unit}", total=total)
        later = progress.add_task(f"{description}: {steps}", total=n_steps)
        yield (lambda m: progress.advance(work, m)), (lambda: progress.advance(later))
