"""What a command does about its start and its end: `imports_kept` around its imports
(`toolkit.app.entry` for typer's, `toolkit.app.cli.map_cmd` for the mapper's), in the mapper's
`numba_tables`, and at the mapper's end `end_without_teardown` (`ends_now` in the entry)."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def imports_kept() -> Iterator[None]:
    """For a command's imports: no garbage collection while they run, then everything made
    so far frozen (`gc.freeze`: the collector leaves it out from then on) and the collector
    back as it was. What imports make (modules, classes, numba's and pandas' tables) lives
    to the end of the process; collecting it meanwhile only walks it: five collections of
    50,000 young objects in a map run's imports, 0.10-0.13 s (load 3), found about 1,200
    objects of garbage (left as they are now)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def numba_tables() -> None:
    """Build numba's typing and lowering tables now, inside `imports_kept`. Numba builds them
    on its first compiled call or cached kernel's load (`CPUContext.refresh`: its
    implementation modules imported, the runtime initialised; about 48,000 objects that live
    to the end); built in the run instead, they cost `toolkit map` one collection of the young
    generation (13-25 ms on the 5,000-scan building, session 22) in its first kernel's load.
    Frozen with the imports, the collector leaves them out; a later refresh is a no-op."""
    from numba.core.registry import cpu_target  # noqa: PLC0415  (on use: numba loads here)

    cpu_target.target_context.refresh()


#: set by a command whose outputs are all written, closed and committed (`end_without_teardown`)
_TEARDOWN_SKIPPABLE = False


def end_without_teardown() -> None:
    """Called by a command at its end, every output written, closed and committed: the
    process may then end without the interpreter's teardown (`ends_now`), which after a map
    run frees every object numba, LLVM and the libraries made, one by one: 0.05-0.07 s of
    `toolkit map` (session 29, corridor and 5,000-scan building), nothing an output needs."""
    global _TEARDOWN_SKIPPABLE
    _TEARDOWN_SKIPPABLE = True


def ends_now() -> bool:
    """Whether `toolkit.app.entry` may end the process now, without the teardown: the command
    asked for it and nothing traces or profiles the process (coverage, cProfile: they write
    their results after the command returns) or keeps it for inspection (`python -i`). If
    so, first what Python's exit does before its teardown: the threads it waits for joined
    (the writers' pool, left to end on its own) and threading's exit callbacks run
    (`threading._shutdown`, as `Py_FinalizeEx` calls it); then `signals.end_now` runs the
    exit handlers, flushes the streams and ends."""
    import sys  # noqa: PLC0415
    import threading  # noqa: PLC0415

    if not (
        _TEARDOWN_SKIPPABLE
        and sys.gettrace() is None
        and sys.getprofile() is None
        and not sys.flags.inspect
    ):
        return False
    threading._shutdown()  # type: ignore[attr-defined]
    return True
