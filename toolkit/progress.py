"""Progress bars for long work: on a terminal only, silent in pipes, tests and CI."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:  # rich (0.03-0.05 s to import) loads only when a bar is shown
    from rich.progress import Progress, TaskID

T = TypeVar("T")


def enabled() -> bool:
    return sys.stderr.isatty() and not os.environ.get("TOOLKIT_NO_PROGRESS")


class _Silent:
    """What a disabled bar does (nothing), without importing rich: the `Progress` methods the
    commands call (`add_task`, `advance`, `update`)."""

    def add_task(self, description: str, total: float | None = None, **_: object) -> int:
        return 0

    def advance(self, task: int, advance: float = 1) -> None:
        pass

    def update(self, task: int, **fields: object) -> None:
        pass


def bar() -> Progress:
    from rich.console import Console  # noqa: PLC0415  # on use, see above
    from rich.progress import (  # noqa: PLC0415
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TaskProgressColumn,
        TextColumn,
        TimeRemainingColumn,
    )

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
    if not enabled():
        yield from items
        return
    with bar() as progress:
        yield from progress.track(items, total=total, description=description)


@contextmanager
def task(description: str, total: float) -> Iterator[tuple[Progress, TaskID]]:
    """A bar advanced by hand: `with task("import", n) as (p, k): p.advance(k, m)`."""
    if not enabled():
        yield _Silent(), 0  # type: ignore[misc]
        return
    with bar() as progress:
        yield progress, progress.add_task(description, total=total)


@contextmanager
def counted(
    description: str, total: float, unit: str, steps: str, n_steps: int
) -> Iterator[tuple[Callable[[float], None], Callable[[], None]]]:
    """Two bars: `total` `unit` counted as the work goes, and `n_steps` fixed `steps` (e.g.
    the outputs), so that the count does not sit at 100% while the steps run. Yields
    (advance the count by m, advance the steps by one)."""
    if not enabled():
        yield (lambda m: None), (lambda: None)
        return
    with bar() as progress:
        work = progress.add_task(f"{description}: {unit}", total=total)
        later = progress.add_task(f"{description}: {steps}", total=n_steps)
        yield (lambda m: progress.advance(work, m)), (lambda: progress.advance(later))
