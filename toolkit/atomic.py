"""Write a directory or a file so that an interrupted command leaves nothing half written."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from toolkit.errors import OutputExistsError


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


@contextmanager
def atomic_dir(out: str | Path, force: bool = False) -> Iterator[Path]:
    """Yield a temporary directory beside `out`; rename it to `out` only if the block succeeds.

    On any exception (or Ctrl-C) the temporary directory is removed and `out` is untouched.
    """
    out = Path(out)
    check_output(out, force)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        _publish_mode(tmp, 0o777)
        yield tmp
        _replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _replace(tmp: Path, out: Path) -> None:
    """Rename `tmp` (a file or a directory) to `out`, replacing whatever `out` is."""
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
    box = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        tmp = box / out.name
        yield tmp
        _replace(tmp, out)
    finally:
        shutil.rmtree(box, ignore_errors=True)


@contextmanager
def atomic_file(out: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside `out`; it replaces `out` only if the block succeeds."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        _publish_mode(tmp, 0o666)
        yield tmp
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
