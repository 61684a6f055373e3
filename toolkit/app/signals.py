"""Signals: SIGTERM and SIGHUP take the same clean path as Ctrl-C.

A batch scheduler, `timeout`, a container stop or a closed terminal send SIGTERM or SIGHUP,
whose default action kills the process at once: no `finally`, no `except BaseException`, so
`toolkit.atomic.atomic_dir` could not remove its temporary directory. Here they raise
`Terminated` (a KeyboardInterrupt) in the main thread, like SIGINT does, and every cleanup
runs. A repeated signal during that cleanup is ignored so that the cleanup finishes (SIGKILL
still stops the process; the next writer then removes what was left).

Light on purpose: imported before anything heavy, so that Ctrl-C in the first second is
handled too.
"""

from __future__ import annotations

import signal
import sys
import threading
from types import FrameType

CAUGHT = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

received: int | None = None  # the first signal caught, if any


class Terminated(KeyboardInterrupt):
    """Raised on SIGTERM or SIGHUP; a KeyboardInterrupt so that it takes Ctrl-C's path."""


def _handle(signum: int, frame: FrameType | None) -> None:
    global received
    if received is not None:  # already stopping: let the cleanup finish
        return
    received = signum
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signal.Signals(signum).name)


def install() -> None:
    """Catch SIGINT, SIGTERM and SIGHUP in this (main) thread; a no-op elsewhere."""
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in CAUGHT:
        if signal.getsignal(sig) is signal.SIG_IGN:  # e.g. nohup: keep ignoring
            continue
        signal.signal(sig, _handle)


def exit_code() -> int:
    """The exit status of a stopped command: 128 + the signal (130 for Ctrl-C)."""
    return 128 + (received or signal.SIGINT)


def stopped_message() -> str:
    name = signal.Signals(received).name if received else "SIGINT"
    return f"interrupted ({name}); no output written"


def exit_stopped() -> None:
    """Print the one line and exit with 128 + signal."""
    print(stopped_message(), file=sys.stderr)
    sys.exit(exit_code())
