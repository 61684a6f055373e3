"""The `toolkit` command's entry point: signal handling first, then the heavy imports."""

from __future__ import annotations

import gc


def main() -> None:
    """Install the signal handlers before typer, numpy or pandas load, so that Ctrl-C or
    SIGTERM at any moment ends with one line and the cleanup, never a traceback."""
    from toolkit.app import signals

    signals.install()
    try:
        from toolkit.app.cli import main as cli_main
    except KeyboardInterrupt:
        signals.exit_stopped()
        return
    try:
        cli_main()
    finally:
        # The command is done, its outputs written and closed. Python's shutdown would now
        # walk every object the libraries made (numba's typing registries above all) in its
        # last garbage collections: 0.3-0.6 s after a map run. Frozen objects are left out
        # of those collections (gc.freeze; gc.disable: no other starts); they are still freed
        # by reference counting, and the standard streams flushed, as usual.
        gc.disable()
        gc.freeze()
