"""What every importer is: a name, a sniffer for `import auto`, a reader, and a writer of its
own format (the simulator writes every format through these, so that tests close the loop)."""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import os
import stat
import zlib
from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, ClassVar

from toolkit.atomic import atomic_dir
from toolkit.dataset import Dataset, write_dataset_files
from toolkit.errors import FormatError, ToolkitError


@dataclass
class ImportOptions:
    """Choices a source format leaves open; each importer reads the ones it needs."""

    rate: float | None = None  # scans per second, for sources without a clock
    scan_topic: str | None = None
    odom_topic: str | None = None
    laser: str | None = None  # which of several lasers is the primary one
    extra: dict[str, str] = field(default_factory=dict)  # -O key=value, format specific

    def get(self, key: str, default: str | None = None) -> str | None:
        return self.extra.get(key, default)


class Importer(ABC):
    """One source format. Subclasses register themselves with `@register`."""

    name: ClassVar[str]
    summary: ClassVar[str]
    #: options this format understands, name -> help (shown by `toolkit import --help-format`)
    options: ClassVar[dict[str, str]] = {}

    @abstractmethod
    def sniff(self, path: Path) -> bool:
        """True if `path` (a file or a directory) looks like this format. Must be cheap."""

    @abstractmethod
    def read(self, sources: Sequence[Path], options: ImportOptions) -> Dataset:
        """Parse the sources into a Dataset whose meta holds the import report."""

    def import_to(
        self, sources: Sequence[Path], out: Path, options: ImportOptions, force: bool = False
    ) -> Path:
        """Read and write the dataset atomically. Streaming importers override this."""
        with atomic_dir(out, force=force) as tmp:
            ds = self.read(sources, options)
            write_dataset_files(ds, tmp)
        return out

    def write(self, ds: Dataset, out: Path, **options: object) -> list[Path]:
        """Write `ds` in this format (files under directory `out`); returns the files."""
        raise ToolkitError(f"format {self.name!r} has no writer")


# ---------------------------------------------------------------- helpers for readers

_MAGIC = {b"\x1f\x8b": gzip.open, b"BZh": bz2.open, b"\xfd7zXZ": lzma.open}


def check_readable(path: Path) -> None:
    """Refuse, before opening it, what is neither a regular file nor a directory: reading a
    FIFO blocks until someone writes to it, a device (/dev/zero) never ends."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise ToolkitError("no such file or directory", file=path) from None
    except OSError as e:
        raise ToolkitError(f"cannot read: {e.strerror}", file=path) from None
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        kind = (
            "a FIFO"
            if stat.S_ISFIFO(mode)
            else "a device"
            if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a socket"
            if stat.S_ISSOCK(mode)
            else "not a regular file"
        )
        raise ToolkitError(f"is {kind}, not a log file; refused", file=path)


def open_binary(path: Path) -> IO[bytes]:
    """Open a file for reading, decompressing gzip, bzip2 or xz by its first bytes."""
    check_readable(path)
    try:
        f = open(path, "rb")  # noqa: SIM115 - returned to the caller
    except FileNotFoundError:
        raise ToolkitError("no such file", file=path) from None
    except IsADirectoryError:
        raise ToolkitError("is a directory, expected a file", file=path) from None
    head = f.read(6)
    f.seek(0)
    for magic, opener in _MAGIC.items():
        if head.startswith(magic):
            f.close()
            return opener(path, "rb")  # type: ignore[operator]
    return f


def open_text(path: Path) -> IO[str]:
    return io.TextIOWrapper(open_binary(path), encoding="utf-8", errors="replace")


def head_bytes(path: Path, n: int = 4096) -> bytes:
    """The first `n` decompressed bytes of a file, or b'' if it cannot be read."""
    try:
        with open_binary(path) as f:
            return f.read(n)
    except (OSError, EOFError, ToolkitError):
        return b""


COMPRESSION_SUFFIXES = (".gz", ".bz2", ".xz")


def strip_compression_suffix(name: str) -> str:
    """`name` without its compression suffixes (any case, repeated: a.log.gz.bz2 -> a.log)."""
    while Path(name).suffix.lower() in COMPRESSION_SUFFIXES:
        name = Path(name).stem
    return name


# ---------------------------------------------------------------- bounded text reading

BLOCK_BYTES = 1 << 20  # decompressed bytes read at a time
MAX_LINE_BYTES = 1 << 20  # no log line is this long (a 10 000-beam scan is ~80 kB)
MAX_RATIO = 50  # decompressed / compressed: real text logs compress 2-5x; a bomb 1000x
MAX_EXTRA_BYTES = 16 << 20  # ... plus this much, for small files of very repetitive text


class TextBlocks:
    """The decompressed text of a log in blocks of whole lines, with bounded memory.

        reader = TextBlocks(path)
        for block in reader:  # str, whole lines; the last one may lack its newline
            ...
        reader.unterminated, reader.error  # after the loop

    A line longer than `MAX_LINE_BYTES` (binary data, /dev/zero's NULs) or a compressed file
    that decompresses to more than `MAX_RATIO` times its size (plus `MAX_EXTRA_BYTES`: a
    decompression bomb) is a FormatError. A damaged compressed stream ends the blocks; its
    error is in `error` (what came before it was read), or a FormatError if nothing came."""

    def __init__(self, path: Path, block: int = BLOCK_BYTES, text: bool = True) -> None:
        self.path = path
        self.block = block
        self.text = text  # False: yield the blocks as bytes
        self.unterminated = False  # the text does not end with a newline
        self.error: str | None = None
        self.bytes = 0  # decompressed bytes read

    def __iter__(self) -> Iterator[Any]:
        compressed = head_raw(self.path).startswith(tuple(_MAGIC))
        limit = self.path.stat().st_size * MAX_RATIO + MAX_EXTRA_BYTES if compressed else None
        # compressed: small reads, so that a damaged stream loses only its last one
        step = min(self.block, 1 << 13) if compressed else self.block
        rest = b""
        with open_binary(self.path) as f:
            done = False
            while not done:
                pieces, have, tail = [rest], 0, len(rest)  # tail: bytes since the last \n
                while have < self.block:  # a block of new data after the cut line
                    try:
                        data = f.read(step)
                    except (OSError, EOFError, lzma.LZMAError, zlib.error) as e:
                        if not self.bytes:
                            raise FormatError(f"cannot read: {e}", file=self.path) from None
                        self.error = str(e)
                        data = b""
                    if not data:
                        done = True
                        break
                    self.bytes += len(data)
                    if limit is not None and self.bytes > limit:
                        raise FormatError(
                            f"decompresses to more than {MAX_RATIO}x its size "
                            f"({self.bytes >> 20} MB so far): not a log (a decompression bomb?)",
                            file=self.path,
                        )
                    pieces.append(data)
                    have += len(data)
                    newline = data.rfind(b"\n")
                    tail = tail + len(data) if newline < 0 else len(data) - newline - 1
                    if tail > MAX_LINE_BYTES:
                        self._long_line()
                data = b"".join(pieces)
                cut = data.rfind(b"\n") + 1
                rest = data[cut:]
                if len(rest) > MAX_LINE_BYTES:
                    self._long_line()
                if cut:
                    yield self._out(data[:cut])
        if rest:
            self.unterminated = True
            yield self._out(rest)

    def _out(self, data: bytes) -> str | bytes:
        return data.decode("utf-8", errors="replace") if self.text else data

    def _long_line(self) -> None:
        raise FormatError(
            f"a line longer than {MAX_LINE_BYTES >> 20} MB after {self.bytes} bytes: "
            "not a text log",
            file=self.path,
        )


def head_raw(path: Path, n: int = 6) -> bytes:
    """The first `n` bytes of the file as stored (compressed or not)."""
    check_readable(path)
    with open(path, "rb") as f:
        return f.read(n)
