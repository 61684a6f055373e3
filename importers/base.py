"""What every importer is: a name, a sniffer for `import auto`, a reader, and a writer of its
own format (the simulator writes every format through these, so that tests close the loop)."""

from __future__ import annotations

import bz2
import dataclasses
import gzip
import io
import lzma
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, ClassVar, Generic, Self, TypeVar, cast

from toolkit.atomic import atomic_dir
from toolkit.dataset import Dataset, write_dataset_files
from toolkit.errors import ToolkitError
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


def open_binary(path: Path) -> IO[bytes]:
    """Open a file for reading, decompressing gzip, bzip2 or xz by its first bytes."""
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
