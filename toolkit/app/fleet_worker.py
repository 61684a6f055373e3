"""Preloaded into every worker of a LocalCluster (`toolkit.app.fleet.client_for`): the worker
process is killed by the kernel the moment the process that started it (the command, where
the scheduler and the nannies run) dies.

Dask's own guard, a thread in the worker that exits when a pipe from the parent closes,
races the worker's event loop: a command killed outright (SIGKILL, the out-of-memory killer)
while its scheduler had not yet answered a heartbeat left the workers' heartbeats failing
first, and each printed "Failed to communicate with scheduler during heartbeat" with a
traceback onto the command's stderr (seen under load; a parent stalled 1.5 s before its
SIGKILL did it in 3 of 6 runs). Here the kernel sends SIGKILL instead (Linux's
PR_SET_PDEATHSIG): nothing of the worker runs after its parent is gone. Elsewhere this does
nothing and Dask's guard stays.

Small on purpose: every worker imports it when it starts.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from distributed import Worker

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
PR_GET_PDEATHSIG = 2


def die_with_parent() -> bool:
    """Ask the kernel for SIGKILL when this process's parent dies (Linux); True if asked.
    A parent already gone (it died before the request) kills this process at once."""
    if sys.platform != "linux":
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    args = (ctypes.c_ulong(int(signal.SIGKILL)), *[ctypes.c_ulong(0)] * 3)  # unsigned longs
    if libc.prctl(PR_SET_PDEATHSIG, *args) != 0:
        return False  # refused (a sandbox's filter): Dask's own guard stays
    parent = multiprocessing.parent_process()
    if parent is not None and os.getppid() != parent.pid:
        os.kill(os.getpid(), signal.SIGKILL)
    return True


def parent_death_signal() -> int:
    """The signal this process gets when its parent dies (0: none, or not Linux)."""
    if sys.platform != "linux":
        return 0
    value = ctypes.c_int(0)
    ctypes.CDLL(None).prctl(PR_GET_PDEATHSIG, ctypes.byref(value), *[ctypes.c_ulong(0)] * 3)
    return value.value


def dask_setup(worker: Worker) -> None:
    """Dask's preload hook: runs in the worker process's main thread as the worker starts,
    before it registers with the scheduler. The parent, for the kernel, is the thread of the
    nanny (in the command) that started this process; it ends only after this process has
    exited, or when the command dies."""
    die_with_parent()
