"""The `toolkit` command's entry point: signal handling first, then the heavy imports."""

from __future__ import annotations


def main() -> None:
    """Install the signal handlers before typer, numpy or pandas load, so that Ctrl-C or
    SIGTERM at any moment ends with one line and the cleanup, never a traceback."""
    import os

    # Arrow's default pool (mimalloc) keeps what it frees: an import that writes row group
    # after row group peaks 45 MB higher with it (bench_import_memory). Read when pyarrow
    # loads, so set here, before; the user's own setting wins.
    os.environ.setdefault("ARROW_DEFAULT_MEMORY_POOL", "system")
    from toolkit.app import signals

    signals.install()
    try:
        from toolkit.app.cli import main as cli_main
    except KeyboardInterrupt:
        signals.exit_stopped()
        return
    cli_main()
