"""The `toolkit` command's entry point: signal handling first, then the heavy imports."""

from __future__ import annotations

import gc

from toolkit.app.startup import ends_now, imports_kept


def main() -> None:
    """Install the signal handlers before typer, numpy or pandas load, so that Ctrl-C or
    SIGTERM at any moment ends with one line and the cleanup, never a traceback."""
    import os
    import sys

    # The imports and numba's first calls make about a million objects that live to the
    # end; Python's collector, by default after every 700 new ones, walks them again and
    # again (0.1-0.3 s of a map run, a tenth of its start). Collections of the young
    # generation after 50,000 instead: the garbage with cycles waits a little longer, the
    # results are the same.
    gc.set_threshold(50_000, 50, 50)

    # Arrow's allocator (mimalloc) keeps freed memory for a while and commits its arenas
    # eagerly: an import that writes row group after row group peaks 45-55 MB higher with
    # its defaults (bench_import_memory: CARMEN 85 MB 236 -> 180 MB, Rawseeds 1 GB 376 ->
    # 344 MB; ~5% more CPU, in madvise). Read when pyarrow loads, so set here, before; the
    # user's own settings win.
    os.environ.setdefault("MIMALLOC_PURGE_DELAY", "0")
    os.environ.setdefault("MIMALLOC_ARENA_EAGER_COMMIT", "0")
    from toolkit.app import signals

    signals.install()
    try:
        with imports_kept():
            from toolkit.app.cli import main as cli_main
    except KeyboardInterrupt:
        signals.exit_stopped()
        return
    except Exception:  # a stop wrapped by an import (see `toolkit.app.cli.main`)
        if signals.received is None:
            raise
        print(signals.stopped_message(), file=sys.stderr)
        signals.end_now(signals.exit_code())  # the broken extension's teardown may fail
        return
    try:
        cli_main()
    except SystemExit as stop:
        if signals.broken_import:  # the interpreter's teardown may fail: skip it
            signals.end_now(stop.code if isinstance(stop.code, int) else 1)
        raise
    finally:
        # The command is done, its outputs written and closed. Python's shutdown would now
        # walk every object the libraries made (numba's typing registries above all) in its
        # last garbage collections: 0.3-0.6 s after a map run. Frozen objects are left out
        # of those collections (gc.freeze; gc.disable: no other starts); they are still freed
        # by reference counting, and the standard streams flushed, as usual.
        gc.disable()
        gc.freeze()
    if signals.received is None and ends_now():  # outputs committed: exit handlers, the end
        signals.end_now(0)
