"""Write a directory or a file so that an interrupted command leaves nothing half written.

`atomic_dir(OUT)` writes into a temporary directory `.OUT.XXXXXXXX.tmp` beside OUT and renames
it into place only when the block succeeds. While it works it holds an exclusive lock on
`.OUT.lock` (flock: released by the kernel when the process dies, however it dies), so that
  - a second writer to the same OUT fails at once instead of silently replacing the first;
  - temporary directories that a killed writer left behind (SIGKILL, a Dask worker killed by
    its nanny, a power cut) are recognised as stale and removed by the next writer.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import TYPE_CHECKING, ParamSpec, TypeVar, cast

from toolkit.errors import OutputExistsError, ToolkitError

if TYPE_CHECKING:
    from concurrent.futures import Future

P = ParamSpec("P")
T = TypeVar("T")

_STOPS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@contextmanager
def _signals_held() -> Iterator[None]:
    """Hold Ctrl-C, SIGTERM and SIGHUP back for a few instructions: between creating a
    temporary and recording its name, and between the two renames that replace an output.
    A signal there would leave a temporary no cleanup knows of, or the old output in the
    trash. The Python handlers are swapped for a recorder (a thread mask would not do: the
    kernel hands a process's signal to any thread that does not block it); a signal that
    came is raised again when the block ends, and takes the usual clean path."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []
    held = {}
    for sig in _STOPS:
        current = signal.getsignal(sig)
        if current not in (signal.SIG_IGN, None):
            held[sig] = signal.signal(sig, lambda signum, frame: came.append(signum))
    try:
        yield
    finally:
        for sig, handler in held.items():
            signal.signal(sig, handler)
        if came:
            signal.raise_signal(came[0])


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _publish_mode(path: Path, mode: int) -> None:
    """mkstemp/mkdtemp create private files; outputs get the modes a plain open() would."""
    os.chmod(path, mode & ~_umask())


def check_output(out: Path, force: bool) -> None:
    """Refuse an existing output unless forced, before any work is done."""
    if out.exists() and not force:
        raise OutputExistsError("exists; pass --force to replace it", file=out)


def lock_path(out: Path) -> Path:
    return out.with_name(f".{out.name}.lock")


@contextmanager
def output_lock(out: Path) -> Iterator[None]:
    """Hold the exclusive lock of output `out`; another holder makes this a one-line error.

    The lock file is removed on release; a waiter that opened the old file re-checks that it
    locked the file now at the path (the classic unlink-safe flock protocol)."""
    path = lock_path(out)
    fd: int | None = None
    try:
        with _signals_held():
            fd = _lock(path, out)
        yield
    finally:
        if fd is not None:
            with suppress(OSError):
                os.unlink(path)
            os.close(fd)


def _lock(path: Path, out: Path) -> int:
    """Open and lock `path` without waiting; the descriptor of the file now at `path`."""
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as e:
            raise _write_error(e, out, None) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise ToolkitError(
                "another toolkit command is writing it now; wait for it or stop it", file=out
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)  # the holder removed the file while we waited: lock the new one


def remove_stale(out: Path) -> list[Path]:
    """Remove the temporary files and directories that killed writers of `out` left beside it
    (call with the output's lock held: then no live writer owns them). Returns what went."""
    pattern = re.compile(rf"\.{re.escape(out.name)}\.([a-z0-9_]{{8}}\.tmp|old-\d+)")
    removed = []
    try:
        siblings = list(out.parent.iterdir())
    except OSError:
        return []
    for p in siblings:
        if pattern.fullmatch(p.name):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
            removed.append(p)
    return removed


def _write_error(e: OSError, out: Path, tmp: Path | None) -> ToolkitError:
    """An OSError while writing `out` as a one-line error naming the user's path (not the
    temporary one) and what went wrong: disk full, read-only, permission denied."""
    name = e.filename
    if name is None:
        where = out
    else:
        where = Path(os.fsdecode(name))
        if tmp is not None:
            with suppress(ValueError):
                where = out / where.relative_to(tmp)
        if where.parent == out.parent and where.name.startswith(f".{out.name}."):
            where = out  # our temporary or lock file beside it: the user knows OUT
    what = {
        errno.ENOSPC: "no space left on the device",
        errno.EDQUOT: "disk quota exceeded",
        errno.EROFS: "read-only file system",
        errno.EACCES: "permission denied",
        errno.EPERM: "operation not permitted",
    }.get(e.errno or 0, e.strerror or str(e))
    return ToolkitError(f"cannot write: {what}; nothing was written", file=where)


_WRITE_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO)


@contextmanager
def atomic_dir(out: str | Path, force: bool = False, update: bool = False) -> Iterator[Path]:
    """Yield a temporary directory beside `out`; rename it to `out` only if the block succeeds.

    On any exception (or Ctrl-C, SIGTERM) the temporary directory is removed and `out` is
    untouched; after SIGKILL the next writer of `out` removes it. With `update`, the
    temporary directory starts as a copy of `out` (hard links) and replaces it without
    --force: a command that adds files to an existing directory, all or none of them."""
    out = Path(out)
    check_output(out, force or update)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise _write_error(e, out, None) from None
    with output_lock(out):
        remove_stale(out)
        check_output(out, force or update)
        tmp: Path | None = None
        try:
            with _signals_held():
                tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
            _publish_mode(tmp, 0o777)
            if update and out.is_dir():
                shutil.copytree(out, tmp, dirs_exist_ok=True, copy_function=_link_or_copy)
            yield tmp
            if out.exists() and not (force or update):  # created meanwhile by something else
                raise OutputExistsError("appeared while this command ran; not replaced", file=out)
            _replace(tmp, out)
        except BaseException as e:
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
            if isinstance(e, OSError) and (tmp is None or e.errno in _WRITE_ERRORS):
                raise _write_error(e, out, tmp) from None
            raise


class _Task:
    """One writer's state, recorded before the pool sees it: a stop may land inside the
    pool's `submit` (starting a thread waits), after the work was queued but before its
    future came back."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.started = False
        self.cancelled = False
        self.done = threading.Event()


class WriterPool:
    """Threads for writers into an `atomic_dir` that know every task they were given, so
    that `writer_threads` can wait for all of it."""

    def __init__(self, workers: int) -> None:
        # deferred: `toolkit info` imports this module and needs no threads
        from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415

        self._pool = ThreadPoolExecutor(workers)
        self._tasks: list[_Task] = []

    def submit(self, fn: Callable[P, T], /, *args: P.args, **kwargs: P.kwargs) -> Future[T]:
        task = _Task()
        self._tasks.append(task)

        def run() -> T | None:
            with task.lock:
                if task.cancelled:
                    return None
                task.started = True
            try:
                return fn(*args, **kwargs)
            finally:
                task.done.set()

        return cast("Future[T]", self._pool.submit(run))

    def cancel_pending(self) -> None:
        """Keep the tasks not started yet from starting (those running go on)."""
        for task in self._tasks:
            with task.lock:
                task.cancelled = not task.started

    def join(self) -> None:
        """Wait for every task; a stop that lands in the wait cancels the tasks not started,
        waits for the running ones, and goes on."""
        try:
            self._wait()
        except BaseException:
            self.cancel_pending()
            self._wait()
            raise
        finally:
            self._pool.shutdown(wait=False)

    def _wait(self) -> None:
        for task in self._tasks:
            with task.lock:
                waits = not task.cancelled
            if waits:
                task.done.wait()


@contextmanager
def writer_threads(workers: int) -> Iterator[WriterPool]:
    """A thread pool for writers into an `atomic_dir`, used inside it: every task it was given
    has ended when the block is left, however it is left. A plain pool's exit joins its
    threads, but a Ctrl-C that lands in that join leaves them writing while `atomic_dir`
    removes the temporary directory (a late file then keeps it), and an interrupted
    `Thread.join` cannot be taken again (CPython marks the thread stopped). So the tasks'
    futures are waited on, again after a stop (a second signal is ignored by
    `toolkit.app.signals` during the cleanup), and tasks not started yet are cancelled."""
    pool = WriterPool(workers)
    try:
        yield pool
    except BaseException:
        pool.cancel_pending()
        raise
    finally:
        pool.join()


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _replace(tmp: Path, out: Path) -> None:
    """Rename `tmp` (a file or a directory) to `out`, replacing whatever `out` is. Signals
    wait: stopped between the two renames, the old output would be left in the trash."""
    with _signals_held():
        _swap(tmp, out)


def _swap(tmp: Path, out: Path) -> None:
    if out.exists():
        trash = out.with_name(f".{out.name}.old-{os.getpid()}")
        os.replace(out, trash)
        os.replace(tmp, out)
        if trash.is_dir():
            shutil.rmtree(trash, ignore_errors=True)
        else:
            trash.unlink(missing_ok=True)
    else:
        os.replace(tmp, out)


@contextmanager
def atomic_path(out: str | Path) -> Iterator[Path]:
    """Yield a path beside `out` that does not exist yet, for a writer that must create it
    itself (a ROS bag: a file, or a directory for ROS 2); it replaces `out`, file or
    directory, only if the block succeeds, and nothing is left behind otherwise."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    box: Path | None = None
    try:
        with _signals_held():
            box = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
        tmp = box / out.name
        yield tmp
        _replace(tmp, out)
    finally:
        if box is not None:
            shutil.rmtree(box, ignore_errors=True)


@contextmanager
def atomic_file(out: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside `out`; it replaces `out` only if the block succeeds."""
    out = Path(out)
    tmp: Path | None = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with _signals_held():
            fd, name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
            os.close(fd)
            tmp = Path(name)
        _publish_mode(tmp, 0o666)
        yield tmp
        os.replace(tmp, out)
    except BaseException as e:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        if isinstance(e, OSError) and (tmp is None or e.errno in _WRITE_ERRORS):
            raise _write_error(e, out, None) from None
        raise
