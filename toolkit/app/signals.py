"""Signals: SIGTERM and SIGHUP take the same clean path as Ctrl-C.

A batch scheduler, `timeout`, a container stop or a closed terminal send SIGTERM or SIGHUP,
whose default action kills the process at once: no `finally`, no `except BaseException`, so
`toolkit.atomic.atomic_dir` could not remove its temporary directory. Here they raise
`Terminated` (a KeyboardInterrupt) in the main thread, like SIGINT does, and every cleanup
runs. A repeated signal during that cleanup is ignored so that the cleanup finishes (SIGKILL
still stops the process; the next writer then removes what was left).

Two places swallow or spoil the raised stop, both seen on a cold start (numba compiling,
open3d loading):
- a callback from C (llvmlite's object cache, a `__del__`) cannot pass an exception on:
  Python prints "Exception ignored" and the command runs to the end. The unraisable hook
  sees our own exception there and raises the stop again where Python code runs next;
- an extension module whose initialisation the stop broke (open3d's pybind module: an
  ImportError "initialization failed") can fail the interpreter's teardown, which then
  ends the process with status 1 instead of 128+N. Such a stop ends the process at once
  after the exit handlers (`end_now`).

Light on purpose: imported before anything heavy, so that Ctrl-C in the first second is
handled too.
"""

from __future__ import annotations

import _thread
import atexit
import contextlib
import os
import signal
import sys
import threading
import time
from types import FrameType

CAUGHT = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

received: int | None = None  # the first signal caught, if any
broken_import = False  # the stop broke an extension module's initialisation
_raised: KeyboardInterrupt | None = None  # the exception the first signal raised
_again = False  # that exception was swallowed: the next signal call raises it anew
_in_hook = False  # the unraisable hook is handling our swallowed stop


class Terminated(KeyboardInterrupt):
    """Raised on SIGTERM or SIGHUP; a KeyboardInterrupt so that it takes Ctrl-C's path."""


def _handle(signum: int, frame: FrameType | None) -> None:
    global received, _raised, _again
    if _again:  # the stop was swallowed by a callback from C: raise it here instead
        _again = False
        signum = received or signum
    elif received is not None:  # already stopping: let the cleanup finish
        return
    received = signum
    _raised = (
        KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signal.Signals(signum).name)
    )
    raise _raised


def _unraisable(info: sys.UnraisableHookArgs) -> None:
    """Our stop, swallowed where an exception cannot propagate: deliver it again."""
    global _again, _in_hook
    if _raised is not None and info.exc_value is _raised and received is not None:
        _in_hook = True
        try:
            _again = True
            # tripped from here, the handler would run inside this hook and be swallowed
            # again; a bare thread, as `Thread.start` waits in this hook for it to start
            # (a loaded machine kept the main thread there past the delivery: "ran on")
            _thread.start_new_thread(_deliver_again, ())
        finally:
            _in_hook = False
        return
    sys.__unraisablehook__(info)


def _deliver_again() -> None:
    """From another thread: the main thread's next Python instruction takes the stop, once
    it has left the hook."""
    time.sleep(0.01)
    while _in_hook:
        time.sleep(0.005)
    if _again and received is not None:
        _thread.interrupt_main(signal.Signals(received))


def install() -> None:
    """Catch SIGINT, SIGTERM and SIGHUP in this (main) thread; a no-op elsewhere."""
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in CAUGHT:
        if signal.getsignal(sig) is signal.SIG_IGN:  # e.g. nohup: keep ignoring
            continue
        signal.signal(sig, _handle)
    sys.unraisablehook = _unraisable


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


def end_now(code: int) -> None:
    """End the process with `code` after the exit handlers, without the interpreter's
    teardown: for a stop that broke an extension module's initialisation."""
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)
