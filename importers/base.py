"""What every importer is: a name, a sniffer for `import auto`, a reader, and a writer of its
own format (the simulator writes every format through these, so that tests close the loop)."""

from __future__ import annotations

import bz2
import dataclasses
import gzip
import io
import lzma
import os
import stat
import tempfile
import zlib
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, ClassVar, Generic, Self, TypeVar, cast

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.atomic import atomic_dir
from toolkit.dataset import (
    GROUNDTRUTH,
    MAX_POSITION,
    ODOMETRY,
    Dataset,
    ImportReport,
    describe_schema,
    pose_frame,
    write_dataset_files,
)
from toolkit.errors import FormatError, ToolkitError
from toolkit.typed import build, check_fields, choices, field_types, words


@dataclass
class ImportOptions:
    """What the user asked for on the command line, as text: the common flags and the
    `-O KEY=VALUE` pairs. The registry turns it, once, into the format's typed options
    (`Importer.Options`); an option the format does not have is an error there."""

    rate: float | None = None  # --rate: scans per second, for sources without a clock
    scan_topic: str | None = None  # --scan-topic
    odom_topic: str | None = None  # --odom-topic
    laser: str | None = None  # --laser: which of several lasers is the primary one
    extra: dict[str, str] = field(default_factory=dict)  # -O key=value, format specific


T = TypeVar("T")

#: the command line's flags that set a format option of the same name
FLAGS = {"rate": "--rate", "scan_topic": "--scan-topic", "odom_topic": "--odom-topic",
         "laser": "--laser"}  # fmt: skip


def option(default: T, help: str = "", *, shown: str | None = None, positive: bool = False) -> T:
    """A field of a format's options: its default, its help line, and (when the default is
    None because the reader decides) the default to show; `positive`: must be > 0."""
    meta = {"help": help, "shown": shown, "positive": positive}
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class FormatOptions:
    """A format's options: a frozen dataclass whose fields (declared with `option`) are the
    `-O` keys, typed (`float`, `int`, `bool`, `str`, `Literal[...]` choices, or `... | None`).
    Built from text by `parse`, from Python by the constructor: both convert and check."""

    #: how errors name the options: the format ("carmen"), set by `register`
    what: ClassVar[str] = "format"

    def __post_init__(self) -> None:
        what = self.what
        check_fields(self, what)
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.metadata.get("positive") and value is not None and not value > 0:
                raise ToolkitError(f"{f.name}={value} for {what}: must be positive")

    @classmethod
    def parse(cls, values: Mapping[str, object]) -> Self:
        """The options from `KEY=VALUE` text (or plain values); unknown keys are an error."""
        return build(cls, values, cls.what)

    @classmethod
    def specs(cls, flags: bool = True) -> list[OptionSpec]:
        """Each option: name, type in words, choices, default and help (`toolkit formats`);
        `flags`: name the command-line flag that sets an option too (reading only)."""
        kinds = field_types(cls)
        out = []
        for f in dataclasses.fields(cls):
            default = f.metadata.get("shown") or _text(f.default)
            flag = FLAGS.get(f.name) if flags else None
            help_ = f.metadata.get("help", "")
            out.append(
                OptionSpec(
                    f.name, words(kinds[f.name]), choices(kinds[f.name]), default, help_, flag
                )
            )
        return out


def _text(value: object) -> str:
    """A default as the text that sets it: true/false, none as '-'."""
    if value is None:
        return "-"
    return str(value).lower() if isinstance(value, bool) else str(value)


@dataclass(frozen=True)
class OptionSpec:
    """One option as `toolkit formats` prints it."""

    name: str
    type: str  # in plain words: number, integer, text, true|false, a|b|c
    choices: tuple[object, ...]
    default: str
    help: str
    flag: str | None = None  # the command-line flag that sets it too (--rate), if any


R = TypeVar("R", bound=FormatOptions)
W = TypeVar("W", bound=FormatOptions)


class Importer(ABC, Generic[R, W]):
    """One source format. Subclasses register themselves with `@register`."""

    name: ClassVar[str]
    summary: ClassVar[str]
    #: the format's options when reading (the `-O` keys, and --rate/--laser/... it takes)
    Options: type[R]
    #: the writer's options, or None if the format has no writer
    WriteOptions: type[W] | None = None

    @abstractmethod
    def sniff(self, path: Path) -> bool:
        """True if `path` (a file or a directory) looks like this format. Must be cheap."""

    @abstractmethod
    def read(self, sources: Sequence[Path], options: R) -> Dataset:
        """Parse the sources into a Dataset whose meta holds the import report."""

    def import_to(
        self, sources: Sequence[Path], out: Path, options: R, force: bool = False
    ) -> Path:
        """Read and write the dataset atomically. Streaming importers override this."""
        with atomic_dir(out, force=force) as tmp:
            ds = self.read(sources, options)
            write_dataset_files(ds, tmp)
        return out

    def write(self, ds: Dataset, out: Path, options: W | None = None) -> list[Path]:
        """Write `ds` in this format (files under directory `out`); returns the files."""
        raise ToolkitError(f"format {self.name!r} has no writer")

    @property
    def writes(self) -> bool:
        """True if the format has a writer."""
        return self.WriteOptions is not None


# ---------------------------------------------------------------- helpers for readers

_MAGIC = {b"\x1f\x8b": gzip.open, b"BZh": bz2.open, b"\xfd7zXZ": lzma.open}


def host_stamps(t: np.ndarray, clock_jitter: float, rng: np.random.Generator) -> np.ndarray:
    """The scans' times `t` as a host that stamps each scan when it reads it writes them:
    spread by `clock_jitter` (sd, s, drawn from `rng`) and kept in order; `t` at 0."""
    stamps = np.asarray(t, np.float64)
    if clock_jitter > 0:
        stamps = np.maximum.accumulate(stamps + rng.normal(0.0, clock_jitter, len(stamps)))
    return stamps


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
            return cast("IO[bytes]", opener(path, "rb"))  # type: ignore[operator]
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


def looks_like_tum(head: bytes) -> bool:
    """True if the text is a TUM trajectory (`t x y z qx qy qz qw` lines, unit quaternions):
    what `toolkit map` writes and evo reads, a trajectory and not a laser log."""
    rows = []
    for line in head.split(b"\n")[:-1][:50]:
        line = line.strip()
        if not line or line.startswith(b"#"):
            continue
        try:
            rows.append([float(tok) for tok in line.split()])
        except ValueError:
            return False
    if not rows or any(len(r) != 8 for r in rows):
        return False
    return all(abs(sum(q * q for q in r[4:]) - 1.0) < 1e-3 for r in rows)


#: what a file's first bytes say it is, when it is no laser log of any format
NOT_A_LOG = (
    (b"PAR1", "a Parquet file (a dataset's or a run's: `toolkit info`, `toolkit map` read them)"),
    (b"ply", "a PLY point cloud"),
    (b"\x89PNG", "a PNG image"),
    (b"{", "a JSON file"),
)


def not_a_log(path: Path) -> str | None:
    """Why `path` is no laser log (the toolkit's own outputs: Parquet, JSON, PLY, PNG, a TUM
    trajectory), or None. Auto-detection and directory walks refuse these."""
    if not path.is_file():
        return None
    head = head_bytes(path, 8192)
    for magic, what in NOT_A_LOG:
        if head.lstrip().startswith(magic):
            return what
    if looks_like_tum(head):
        return "a TUM trajectory (t x y z qx qy qz qw)"
    return None


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


# ---------------------------------------------------------------- rows kept out of memory

SPILL_BLOCK_BYTES = 1 << 20  # bytes of rows held before they go to disk, and read back at a time


class RowSpill:
    """Rows of numbers (an N x width array of one dtype) appended block by block and read back
    block by block: in memory (`where=None`, for `Importer.read`), or, once they pass
    `SPILL_BLOCK_BYTES`, in an unnamed temporary file in the directory `where` (an import's
    output folder, on disk: not /tmp, which may be RAM), so that a log's converted values never
    sit in memory all at once. The file has no name (O_TMPFILE where the system has it), so
    nothing is left behind if the process dies."""

    def __init__(self, width: int, dtype: type = np.float32, where: Path | None = None) -> None:
        self.width = width
        self.dtype = np.dtype(dtype)
        self.where = where
        self.rows = 0
        self._blocks: list[np.ndarray] = []
        self._held = 0  # bytes in _blocks
        self._file: io.BufferedRandom | None = None

    @property
    def spilled(self) -> bool:
        return self._file is not None

    def append(self, block: np.ndarray) -> None:
        block = np.ascontiguousarray(block, dtype=self.dtype).reshape(-1, self.width)
        if not len(block):
            return
        self.rows += len(block)
        self._blocks.append(block)
        self._held += block.nbytes
        if self.where is not None and self._held >= SPILL_BLOCK_BYTES:
            if self._file is None:
                self._file = tempfile.TemporaryFile(dir=self.where, prefix=".spill-")  # noqa: SIM115 - closed by close()
            self._file.seek(0, os.SEEK_END)
            for b in self._blocks:
                self._file.write(b.data.cast("B"))
            self._blocks, self._held = [], 0

    def blocks(self, rows: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """(index of its first row, block) in order; blocks of about `rows` rows (default:
        `SPILL_BLOCK_BYTES` of them), whatever the blocks appended."""
        if rows is None:
            rows = max(1, SPILL_BLOCK_BYTES // max(1, self.width * self.dtype.itemsize))
        at = 0
        if self._file is not None:
            self._file.seek(0)
            on_disk = self._on_disk
            while at < on_disk:
                out = np.empty((min(rows, on_disk - at), self.width), self.dtype)
                if self._file.readinto(out.data.cast("B")) != out.nbytes:
                    raise OSError("spill file ended early")
                yield at, out
                at += len(out)
        pending: list[np.ndarray] = []
        have = 0
        for block in self._blocks:
            pending.append(block)
            have += len(block)
            if have >= rows:
                yield at, np.concatenate(pending) if len(pending) > 1 else pending[0]
                at, pending, have = at + have, [], 0
        if pending:
            yield at, np.concatenate(pending) if len(pending) > 1 else pending[0]

    def take(self, keep: np.ndarray, rows: int | None = None) -> Iterator[np.ndarray]:
        """The rows where the mask `keep` (one bool per row) is True, block by block; the
        blocks are the caller's to change."""
        for at, block in self.blocks(rows):
            mask = keep[at : at + len(block)]
            if self._file is not None and at + len(block) <= self._on_disk and mask.all():
                yield block  # read from the file: a copy already
            elif mask.any():
                yield block[mask]

    @property
    def _on_disk(self) -> int:
        return self.rows - sum(len(b) for b in self._blocks)

    def row(self, i: int) -> np.ndarray:
        """Row `i` (a copy)."""
        if not 0 <= i < self.rows:
            raise IndexError(i)
        if self._file is not None and i < self._on_disk:
            out = np.empty(self.width, self.dtype)
            self._file.seek(i * out.nbytes)
            if self._file.readinto(out.data.cast("B")) != out.nbytes:
                raise OSError("spill file ended early")
            return out
        i -= self._on_disk
        for block in self._blocks:
            if i < len(block):
                row: np.ndarray = block[i].copy()
                return row
            i -= len(block)
        raise IndexError(i)

    def close(self) -> None:
        """Free the rows (the file, or the blocks)."""
        self._blocks, self._held, self.rows = [], 0, 0
        if self._file is not None:
            self._file.close()
            self._file = None


def write_pose_blocks(
    path: Path, blocks: Iterator[np.ndarray], report: ImportReport, what: str
) -> None:
    """A pose table (t, x, y, theta rows, block by block) with the schema and content
    `write_poses` gives the whole frame, one row group per block, after the check
    `plausible_poses` makes (a non-finite field, a position beyond `MAX_POSITION`: dropped,
    counted in `report` under `what`)."""
    kind = {ODOMETRY: "odometry", GROUNDTRUTH: "groundtruth"}.get(path.name, "poses")
    empty = pose_frame(np.empty(0), np.empty((0, 3)))
    schema = describe_schema(pa.Table.from_pandas(empty, preserve_index=False).schema, kind)
    dropped, row, first = 0, 0, None
    # no dictionary: in row groups of 10^5 poses, the unique float64 values only pay for one
    # (a 727k-pose odometry: 13.8 MB plain, 17.8 MB with; 14.9 MB as one group with)
    with pq.ParquetWriter(path, schema, compression="zstd", use_dictionary=False) as writer:
        for block in blocks:
            bad = ~np.isfinite(block).all(axis=1) | (np.abs(block[:, 1:3]) > MAX_POSITION).any(1)
            if bad.any():
                i = int(np.argmax(bad))
                first = first or (row + i, block[i])
                dropped += int(bad.sum())
                block = block[~bad]
            row += len(bad)
            columns = [pa.array(np.ascontiguousarray(block[:, k])) for k in range(4)]
            writer.write_batch(pa.RecordBatch.from_arrays(columns, schema=schema))
    if first is not None:
        at, (t, x, y, _) = first
        report.drop(
            f"{what}: implausible pose (non-finite, or beyond {MAX_POSITION:.0e} m)",
            dropped,
            f"row {at} (t={float(t)!r}, x={float(x)!r}, y={float(y)!r})",
        )
