"""The `toolkit` command's entry point: signal handling first, then the heavy imports."""

from __future__ import annotations


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
    cli_main()
