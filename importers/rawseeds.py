"""Rawseeds (Bicocca, Bovisa) session CSVs: SICK and Hokuyo lasers, odometry, ground truth.

A session is a directory of comma-separated files without header, each `<session>-<STREAM>.csv`
(optionally `.bz2`); see FORMATS.md "Rawseeds". A session dir or single files are accepted;
a file with another name is taken as SICK_FRONT if its first line has the SICK layout.
The laser CSVs of a session run to gigabytes, so lasers are streamed: the decompressed text is
cut at line ends into ~12 MB chunks; this thread parses chunk k+1 with pyarrow's multithreaded
CSV reader while a worker turns chunk k into an S x B float32 array and appends it to a
`ScansWriter`; the sources' sha256 is computed on a third thread. Memory stays at a few
chunks whatever the file size (about 0.5 GB peak RSS for a 1 GB CSV).

Decisions (also stored in meta.json under "rawseeds"):

- Primary laser: SICK_FRONT unless `--laser` names another (sick_front, sick_rear,
  hokuyo_front, hokuyo_rear); every other laser found goes to `scans-<name>.parquet`.
- No return: the SICK LMS-2xx in cm mode reports no echo and dazzle as codes 8183..8191 cm,
  i.e. 81.83..81.91 m, and some drivers write 0. Rawseeds' documentation shows no special
  value, so readings >= 81.83 m (`range_max`) or == 0 become NaN; the writer writes NaN as
  81.910 (the LMS "no echo" code). Hokuyo URG-04LX: readings < 0.02 m (its error codes) or
  > 5.6 m become NaN. NaN, inf and negative readings become NaN too; both kinds are counted in
  meta["range_readings"].
- Ground truth (`-O groundtruth=`): `floor` (default) is GROUNDTRUTH.csv, the independent
  external ground truth (cameras and external lasers) in a frame fixed on the floor of the GT
  area, covering only part of the path; `extended` is GT-extended.csv, the whole path in the
  frame of the first robot pose, from scan matching on the robot's own lasers (so not
  independent of them); `none`. The file not chosen is kept as a pose stream
  (`poses-gt-floor.parquet` or `poses-gt-extended.parquet`).
- `<session>.relations` (Freiburg: pose of t2 in the frame of t1, for RPE) is kept as
  `relations.parquet` (t1, t2, x, y, z, roll, pitch, yaw), in file order.
- `*-GROUNDTRUTH-CARTOGRAPHER.csv` is a SLAM estimate added by a later repository, not ground
  truth: kept as `poses-cartographer.parquet`, never as ground truth (its `.relations` file
  is ignored).
- SICK `angular_offset` [1/4 deg]: angle_min is -90 deg plus the most common offset (0 in
  every file we write); the counts per value are in meta. Hokuyo mounting is not documented
  beyond a 12.5 deg downward tilt: x = y = z = 0, yaw 0 (front) or pi (rear), noted.
- Writer (`write`, used by the simulator): SICK_FRONT (181 beams at 1 deg only; t with 6
  decimals, ranges with 3, NaN as 81.910), ODOMETRY_XYT (ticks 0; x, y, theta with 3
  decimals as the Rawseeds odometry example line), GROUNDTRUTH (6 decimals, zero covariance).
- Damage that a long recording can carry is skipped and counted in the import report: lines
  with the wrong number of fields, an `n_ranges` field that does not match, a truncated last
  line, timestamps out of order (the out-of-order record is dropped, file order kept). A
  non-numeric value is an error naming the file and line: the fast parser fails, then a slow
  pass over that chunk finds the line.
"""

from __future__ import annotations

import concurrent.futures
import hashlib
import json
import math
import re
import tempfile
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, ClassVar, Literal

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
from rich.progress import TaskID

from importers import register
from importers.base import FormatOptions, Importer, head_bytes, open_binary, option
from toolkit.atomic import atomic_dir, atomic_file
from toolkit.dataset import (
    GROUNDTRUTH,
    META,
    ODOMETRY,
    SCANS,
    Dataset,
    ImportReport,
    LaserGeometry,
    ScansWriter,
    load,
    make_meta,
    plausible_poses,
    pose_frame,
    write_poses,
)
from toolkit.errors import FormatError, ToolkitError
from toolkit.progress import task

# decompressed text handed to one multithreaded parse: 12 MB keeps peak RSS ~0.4 GB (32 MB:
# ~0.5 GB) at the same CPU cost in our A/B runs
CHUNK_BYTES = 12 << 20
COMPRESSED_READ = 1 << 20  # a truncated compressed stream loses at most this much
SICK_RANGE_MAX = 81.83  # first LMS-2xx error code in cm mode (8183 cm); at or above = no return
SICK_NO_RETURN = 81.91  # what the writer writes for NaN: the LMS "no echo" code 8191 cm
HOKUYO_RANGE_MIN = 0.02  # URG-04LX error codes are 0..19 mm
HOKUYO_RANGE_MAX = 5.6
HOKUYO_STEP = 2.0 * math.pi / 1024.0
RELATIONS = "relations.parquet"
RELATION_COLUMNS = ("t1", "t2", "x", "y", "z", "roll", "pitch", "yaw")


@dataclass(frozen=True)
class LaserSpec:
    """One Rawseeds laser stream: its file suffix, columns before the ranges, and geometry."""

    stream: str  # file suffix, e.g. SICK_FRONT
    name: str  # dataset name, e.g. sick_front
    lead: int  # columns before the ranges: t, n_ranges, angular_offset (SICK) or t (Hokuyo)
    geometry: LaserGeometry

    @property
    def columns(self) -> int:
        return self.lead + self.geometry.beams


def _sick(stream: str, **mount: float) -> LaserSpec:
    geometry = LaserGeometry.sick_180(181, range_max=SICK_RANGE_MAX, **mount)
    return LaserSpec(stream, stream.lower(), 3, geometry)


def _hokuyo(stream: str, yaw: float) -> LaserSpec:
    geometry = LaserGeometry(
        681, -340 * HOKUYO_STEP, HOKUYO_STEP, HOKUYO_RANGE_MAX, HOKUYO_RANGE_MIN, yaw=yaw
    )
    return LaserSpec(stream, stream.lower(), 1, geometry)


LASERS: dict[str, LaserSpec] = {
    s.name: s
    for s in (
        _sick("SICK_FRONT", x=0.080, y=0.0, z=0.45),
        _sick("SICK_REAR", x=-0.463, y=0.001, z=0.454, yaw=math.pi),
        _hokuyo("HOKUYO_FRONT", 0.0),
        _hokuyo("HOKUYO_REAR", math.pi),
    )
}
# pose-like streams: file suffix -> (number of fields, name)
POSE_STREAMS = {
    "ODOMETRY_XYT": 7,
    "GROUNDTRUTH": 13,
    "GT-extended": 4,
    "GROUNDTRUTH-CARTOGRAPHER": 4,
}
_STREAM_RE = "|".join(
    re.escape(s)
    for s in sorted([*POSE_STREAMS, *(x.stream for x in LASERS.values())], key=len)[::-1]
)
NAME_RE = re.compile(rf"^(?P<session>.+?)-(?P<stream>{_STREAM_RE})\.csv(?:\.bz2|\.gz)?$")
RELATIONS_RE = re.compile(
    r"^(?P<session>.+?)(?<!-GROUNDTRUTH-CARTOGRAPHER)\.relations(?:\.bz2|\.gz)?$"
)
GT_CHOICES = ("floor", "extended", "none")


def classify(path: Path) -> tuple[str, str] | None:
    """(session, stream) of a Rawseeds file name; stream 'relations' for `<session>.relations`."""
    if m := NAME_RE.match(path.name):
        return m["session"], m["stream"]
    if m := RELATIONS_RE.match(path.name):
        return m["session"], "relations"
    return None


def _looks_like_sick_line(line: bytes) -> bool:
    fields = line.split(b",")
    if len(fields) != 184:
        return False
    try:
        values = [float(f) for f in fields]
    except ValueError:
        return False
    return values[1] == 181.0 and values[0] > 0


# ---------------------------------------------------------------- reading text in chunks


def _open_stream(path: Path) -> IO[bytes]:
    """Decompressed bytes of `path`: pyarrow's bz2/gzip streams, else open_binary (plain, xz)."""
    magic = _raw_magic(path)
    if magic.startswith(b"BZh") or magic.startswith(b"\x1f\x8b"):
        kind = "bz2" if magic.startswith(b"BZh") else "gzip"
        return pa.input_stream(str(path), compression=kind)
    return open_binary(path)


def _raw_magic(path: Path) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(3)
    except FileNotFoundError:
        raise ToolkitError("no such file", file=path) from None
    except IsADirectoryError:
        raise ToolkitError("is a directory, expected a file", file=path) from None


@dataclass
class Chunk:
    """Whole lines of text, where they start in the file, and whether the file ends here
    without a final newline (then the last line may be cut short)."""

    data: bytes
    first_line: int
    unterminated: bool = False


_COMPRESSED_MAGIC = (b"BZh", b"\x1f\x8b", b"\xfd7z")


def _read(f: IO[bytes], n: int | None, path: Path, notes: list[str]) -> bytes:
    """Up to n (None: all) decompressed bytes; b'' at the end, also at the end of a truncated stream."""
    try:
        return f.read() if n is None else f.read(n)
    except (OSError, EOFError) as e:
        if isinstance(e, EOFError) or "runcated" in str(e):
            notes.append(f"{path.name}: compressed stream ends early; imported what it held")
            return b""
        raise FormatError(f"cannot decompress: {e}", file=path) from None


def chunks(path: Path, notes: list[str], size: int | None = None) -> Iterator[Chunk]:
    """Cut the decompressed text into chunks of whole lines (about CHUNK_BYTES each).
    Compressed streams are read COMPRESSED_READ at a time: a truncated one loses at most that."""
    size = size or CHUNK_BYTES
    line = 1
    rest = b""
    raw_size = path.stat().st_size
    compressed = _raw_magic(path).startswith(_COMPRESSED_MAGIC)
    step = min(size, COMPRESSED_READ) if compressed else size
    with _open_stream(path) as f, task(f"read {path.name}", raw_size) as (bar, tid):
        pieces: list[bytes] = [rest]
        have = 0
        while True:
            block = _read(f, step, path, notes)
            if block:
                pieces.append(block)
                have += len(block)
                if not compressed:
                    bar.advance(TaskID(tid), len(block))
                if have < size:
                    continue
            data = b"".join(pieces)
            cut = data.rfind(b"\n") + 1
            rest = data[cut:]
            if cut:
                yield Chunk(data[:cut] if rest else data, line)
                line += data.count(b"\n", 0, cut)
            if not block:
                break
            pieces, have = [rest], len(rest)
        bar.update(TaskID(tid), completed=raw_size)
    if rest.strip():
        yield Chunk(rest, line, unterminated=True)


def _line_of(chunk: Chunk, text: str) -> int | None:
    pos = chunk.data.find(text.encode())
    return None if pos < 0 else chunk.first_line + chunk.data.count(b"\n", 0, pos)


def _locate_non_numeric(path: Path, chunk: Chunk, arrow_message: str) -> FormatError:
    """The slow pass, run only after the fast parser failed: find the first bad line."""
    for offset, raw in enumerate(chunk.data.split(b"\n")):
        text = raw.strip()
        if not text:
            continue
        fields = re.split(rb"[ \t]*,[ \t]*|[ \t]+", text)
        for k, value in enumerate(fields, start=1):
            try:
                float(value)
            except ValueError:
                shown = value.decode("utf-8", "replace")[:30]
                return FormatError(
                    f"non-numeric value {shown!r} in field {k}",
                    file=path,
                    record=chunk.first_line + offset,
                )
    first = arrow_message.strip().splitlines()[0] if arrow_message.strip() else "parse error"
    end = chunk.first_line + chunk.data.count(b"\n")
    return FormatError(
        f"cannot parse: {first}", file=path, record=f"lines {chunk.first_line}-{end}"
    )


@dataclass
class Parsed:
    """One chunk parsed: a table of float columns, and the rows that had the wrong field count."""

    table: pa.Table
    bad_rows: list[tuple[int, str]] = field(default_factory=list)  # (row number, text)

    @property
    def rows(self) -> int:
        return int(self.table.num_rows)

    def column(self, i: int) -> np.ndarray:
        """Column i as numpy; empty fields are NaN."""
        col = self.table.column(i)
        if col.null_count:
            col = pc.fill_null(col, math.nan)
        return col.to_numpy()

    def fill(self, out: np.ndarray, first: int) -> None:
        """out[:, k] = column first + k. The columns are gathered contiguously (B x S) and
        transposed in one copy: twice as fast as writing each column with a stride of B."""
        columns = np.empty((out.shape[1], out.shape[0]), dtype=out.dtype)
        for k in range(out.shape[1]):
            col = self.table.column(first + k)
            if col.null_count:
                col = pc.fill_null(col, math.nan)
            row = 0
            for piece in col.chunks:
                columns[k, row : row + len(piece)] = piece.to_numpy(zero_copy_only=False)
                row += len(piece)
        out[...] = columns.T


def parse_chunk(
    path: Path,
    chunk: Chunk,
    ncols: int,
    float32_from: int | None = None,
    delimiter: str = ",",
) -> Parsed:
    """Parse a chunk of whole lines with pyarrow (multithreaded); float64 columns, or float32
    from column `float32_from` on. Rows with the wrong number of fields are skipped and kept."""
    names = [f"c{i}" for i in range(ncols)]
    types = {
        n: pa.float32() if float32_from is not None and i >= float32_from else pa.float64()
        for i, n in enumerate(names)
    }
    bad: list[tuple[int, str]] = []
    if not chunk.data.isascii():  # numbers are ASCII; pyarrow's row handler chokes on bad UTF-8
        pos = next(i for i, b in enumerate(chunk.data) if b > 127)
        line = chunk.first_line + chunk.data.count(b"\n", 0, pos)
        raise FormatError(f"not a number: byte 0x{chunk.data[pos]:02x}", file=path, record=line)

    def skip(row: pacsv.InvalidRow) -> str:
        bad.append((row.number if row.number is not None else 1 << 62, str(row.text)))
        return "skip"

    try:
        table = pacsv.read_csv(
            pa.py_buffer(chunk.data),
            read_options=pacsv.ReadOptions(
                column_names=names, use_threads=True, block_size=1 << 22
            ),
            parse_options=pacsv.ParseOptions(
                delimiter=delimiter, quote_char=False, invalid_row_handler=skip
            ),
            convert_options=pacsv.ConvertOptions(column_types=types),
        )
    except pa.ArrowInvalid as e:
        if "Empty CSV" in str(e):
            return Parsed(pa.schema(list(types.items())).empty_table(), bad)
        raise _locate_non_numeric(path, chunk, str(e)) from None
    return Parsed(table, bad)


def _where(chunk: Chunk, text: str) -> str:
    head = text.split(",", 1)[0].strip()[:24]
    line = _line_of(chunk, text)
    return f"line {line} (t={head})" if line is not None else f"t={head}"


def _count_bad_rows(
    path: Path, chunk: Chunk, parsed: Parsed, report: ImportReport, prefix: str, what: str
) -> None:
    """Rows with the wrong number of fields: a truncated last line, or damage in the middle.
    Counted in bulk; only the first of each kind is located, for the report's example."""
    if not parsed.bad_rows:
        return
    tail = chunk.data.rstrip()
    last = [
        r for r in parsed.bad_rows if chunk.unterminated and tail.endswith(r[1].rstrip().encode())
    ]
    middle = [r for r in parsed.bad_rows if not last or r is not last[0]]
    for reason, rows in (("truncated last line", last[:1]), (f"wrong number of {what}", middle)):
        if rows:
            first = min(rows, key=lambda r: r[0])
            report.drop(prefix + reason, len(rows), f"{path.name} {_where(chunk, first[1])}")


def order_mask(t: np.ndarray, prev: float, nxt: float) -> np.ndarray:
    """Keep-mask for non-decreasing time in file order. A record that jumps ahead of both
    neighbours (its successor fits after its predecessor) is the one out of order; then every
    record earlier than one already kept is dropped."""
    ext = np.concatenate(([prev], t, [nxt]))
    spike = (ext[1:-1] > ext[2:]) & (ext[:-2] <= ext[2:])
    keep = ~spike
    kept_t = np.where(keep, t, -np.inf)
    running = np.maximum.accumulate(np.concatenate(([prev], kept_t)))[:-1]
    return keep & (t >= running)


def kept_in_order(
    t: np.ndarray, prev: float, nxt: float, report: ImportReport, prefix: str, path: Path
) -> np.ndarray:
    """`order_mask`, with the records it drops counted in the report (the first one named)."""
    keep = order_mask(t, prev, nxt)
    if not keep.all():
        report.drop(
            prefix + "timestamp out of order",
            int((~keep).sum()),
            f"{path.name} t={t[~keep][0]:.6f}",
        )
    return keep


# ---------------------------------------------------------------- lasers, streamed


@dataclass
class LaserResult:
    rows_read: int = 0
    rows_kept: int = 0
    readings: int = 0
    no_return: int = 0
    invalid: int = 0
    offsets: dict[float, int] = field(default_factory=dict)


def stream_laser(
    path: Path, spec: LaserSpec, out: Path, report: ImportReport, prefix: str = ""
) -> LaserResult:
    """Parse a laser CSV chunk by chunk into a scans Parquet file; drops go to `report`.

    Two stages: this thread reads and parses chunk k+1 (pyarrow, multithreaded) and checks
    its times, while a worker turns chunk k into an S x B array, applies the no-return rules
    and appends it to the Parquet file. Chunk k's order check needs chunk k+1's first time,
    so one parsed chunk waits; memory stays at about three chunks."""
    result = LaserResult()
    notes: list[str] = []
    pending: tuple[Parsed, np.ndarray, np.ndarray] | None = None  # parsed, t, rows ok
    prev_t = -math.inf
    saw_text = False
    writer = ScansWriter(out, spec.geometry.beams)
    pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="rawseeds-scans")
    future: concurrent.futures.Future[None] | None = None

    def hand_over(parsed: Parsed, t: np.ndarray, ok: np.ndarray, nxt: float) -> None:
        nonlocal prev_t, future
        rows = np.flatnonzero(ok)
        rows = rows[kept_in_order(t[rows], prev_t, nxt, report, prefix, path)]
        if len(rows):
            prev_t = float(t[rows[-1]])
        result.rows_kept += len(rows)
        if future is not None:
            future.result()
        future = pool.submit(_write_scans, writer, parsed, t, rows, spec, result)

    try:
        for chunk in chunks(path, notes):
            saw_text = saw_text or not chunk.data.isspace()  # no copy of the chunk
            parsed = parse_chunk(path, chunk, spec.columns, float32_from=spec.lead)
            _count_bad_rows(path, chunk, parsed, report, prefix, "ranges")
            result.rows_read += parsed.rows + len(parsed.bad_rows)
            t, ok = _check_lead(path, parsed, spec, report, prefix, result)
            if not ok.any():
                continue
            if pending is not None:
                hand_over(*pending, nxt=float(t[ok][0]))
            pending = (parsed, t, ok)
        if pending is not None:
            hand_over(*pending, nxt=math.inf)
        if future is not None:
            future.result()
    finally:
        pool.shutdown(wait=True)
        writer.close(_with_offset(spec, result), {"format": "rawseeds", "file": path.name})
    for note in notes:
        report.note(note)
    if not saw_text:
        raise FormatError(
            "empty file" if not notes else "no complete line before the stream ends", file=path
        )
    if result.rows_kept == 0:
        raise FormatError(
            f"no valid scans: {result.rows_read} lines read, all dropped ({_reasons(report)})",
            file=path,
        )
    return result


def _reasons(report: ImportReport) -> str:
    return ", ".join(f"{k}: {v}" for k, v in report.dropped.items()) or "none"


def _check_lead(
    path: Path,
    parsed: Parsed,
    spec: LaserSpec,
    report: ImportReport,
    prefix: str,
    result: LaserResult,
) -> tuple[np.ndarray, np.ndarray]:
    """Times, and which rows have a usable time and (SICK) the right n_ranges field."""
    t = parsed.column(0)
    ok = np.isfinite(t)
    if not ok.all():
        report.drop(prefix + "timestamp not a number", int((~ok).sum()), path.name)
    if spec.lead == 3:
        count = parsed.column(1)
        match = count == spec.geometry.beams
        bad = ok & ~match
        if bad.any():
            report.drop(
                prefix + "n_ranges field does not match the ranges",
                int(bad.sum()),
                f"{path.name} t={t[bad][0]:.6f} n_ranges={count[bad][0]:g}",
            )
        ok &= match
        offsets, counts = np.unique(parsed.column(2)[ok], return_counts=True)
        for value, c in zip(offsets.tolist(), counts.tolist(), strict=True):
            result.offsets[value] = result.offsets.get(value, 0) + int(c)
    return t, ok


def _write_scans(
    writer: ScansWriter,
    parsed: Parsed,
    t: np.ndarray,
    rows: np.ndarray,
    spec: LaserSpec,
    result: LaserResult,
) -> None:
    """The worker's stage: the kept rows as S x B float32, no-return rules, appended."""
    ranges = np.empty((parsed.rows, spec.geometry.beams), dtype=np.float32)
    parsed.fill(ranges, spec.lead)
    if len(rows) != parsed.rows:
        ranges, t = ranges[rows], t[rows]
    g = spec.geometry
    lo, hi = np.float32(g.range_min), np.float32(g.range_max)
    # one pass for the mask of readings that become NaN (comparisons with NaN are False)
    if spec.lead == 1:  # Hokuyo: valid in [range_min, range_max]; below are error codes
        lost = ~((ranges >= lo) & (ranges <= hi))
    else:  # SICK: valid in (0, range_max); 0 and the 8183..8191 cm codes are no return
        lost = ~((ranges > lo) & (ranges < hi))
    n_lost = int(np.count_nonzero(lost))
    if n_lost:
        values = ranges[lost]
        n_invalid = int(np.count_nonzero(~np.isfinite(values) | (values < 0)))
        result.invalid += n_invalid
        result.no_return += n_lost - n_invalid
        np.putmask(ranges, lost, np.float32(np.nan))
    result.readings += ranges.size
    writer.write(t, ranges)


# ---------------------------------------------------------------- small files, whole


def read_rows(path: Path, ncols: int, report: ImportReport, prefix: str) -> np.ndarray:
    """An N x ncols float64 array from a small Rawseeds file (comma, ", " or whitespace
    separated); wrong field counts and a truncated last line are skipped and counted."""
    notes: list[str] = []
    with _open_stream(path) as f:
        data = _read(f, None, path, notes)
    for note in notes:
        report.note(note)
    if not data.strip():
        raise FormatError("empty file", file=path)
    # one separator: "a, b", "a b  c" and "a,b" all become "a,b"
    data = re.sub(rb"(?m)^[ \t]+|[ \t]+(?=\r?$)", b"", data)
    data = re.sub(rb"[ \t]*,[ \t]*|[ \t]+", b",", data)
    unterminated = not data.endswith(b"\n")
    chunk = Chunk(data, 1, unterminated)
    parsed = parse_chunk(path, chunk, ncols)
    _count_bad_rows(path, chunk, parsed, report, prefix, "fields")
    return np.column_stack([parsed.column(i) for i in range(ncols)])


def read_pose_stream(
    path: Path, ncols: int, columns: Sequence[int], report: ImportReport, prefix: str
) -> pd.DataFrame:
    """t, x, y, theta from the given column indices, records out of time order dropped."""
    rows = read_rows(path, ncols, report, prefix)
    rows = rows[np.isfinite(rows[:, 0])]
    rows = rows[kept_in_order(rows[:, 0], -math.inf, math.inf, report, prefix, path)]
    t, x, y, theta = (rows[:, c] for c in columns)
    return pose_frame(t, np.column_stack([x, y, theta]))


# ---------------------------------------------------------------- the session


@dataclass
class Session:
    """The files of one Rawseeds session, by stream."""

    name: str
    files: dict[str, Path]
    where: str  # "session dir X" or "given files", for error messages


def find_session(sources: Sequence[Path]) -> Session:
    files: dict[str, Path] = {}
    sessions: set[str] = set()
    where = "given files"
    for src in sources:
        src = Path(src)
        if src.is_dir():
            where = f"session dir {src}"
            found = [(p, classify(p)) for p in sorted(src.iterdir()) if p.is_file()]
            hits = [(p, c) for p, c in found if c is not None]
            if not hits:
                raise FormatError(
                    "no Rawseeds files (<session>-SICK_FRONT.csv etc.) in directory", file=src
                )
        elif src.is_file():
            c = classify(src)
            if c is None:
                if not _looks_like_sick_line(head_bytes(src, 8192).split(b"\n", 1)[0].strip()):
                    if not head_bytes(src, 64).strip():
                        raise FormatError("empty file", file=src)
                    raise FormatError(
                        "not a Rawseeds file: name is not <session>-<STREAM>.csv and the first "
                        "line is not a SICK record (t, 181, offset, 181 ranges)",
                        file=src,
                    )
                c = (strip_name(src), "SICK_FRONT")
            hits = [(src, c)]
        else:
            raise ToolkitError("no such file or directory", file=src)
        for path, (session, stream) in hits:
            if sessions and session not in sessions:
                others = ", ".join(sorted(sessions | {session}))
                raise FormatError(f"files of several sessions ({others}); give one", file=path)
            if stream in files and files[stream] != path:
                plain = files[stream].name.removesuffix(".bz2") == path.name
                if plain or path.name.removesuffix(".bz2") == files[stream].name:
                    continue  # plain and bz2 copies of the same stream: take the first
                raise FormatError(
                    f"two {stream} files: {files[stream].name} and {path.name}", file=path
                )
            files[stream] = path
            sessions.add(session)
    return Session(next(iter(sessions)), files, where)


def _what_is_there(session: Session) -> str:
    """What a session without the wanted laser holds, for its error: the other lasers (name
    one with --laser), or that it is ground truth alone (the Bicocca folders of
    ../shared/data/real hold only that: a user reads why nothing can be mapped)."""
    lasers = [spec.name for spec in LASERS.values() if spec.stream in session.files]
    if lasers:
        return f"; it has {', '.join(lasers)} (--laser NAME)"
    return f"; it has {', '.join(session.files)} only: no laser scans to import"


def strip_name(path: Path) -> str:
    name = path.name
    for suffix in (".bz2", ".gz", ".csv"):
        name = name.removesuffix(suffix)
    return name


@dataclass(frozen=True)
class RawseedsOptions(FormatOptions):
    """Reading a Rawseeds session."""

    groundtruth: Literal["floor", "extended", "none"] = option(
        "floor",
        "floor: GROUNDTRUTH.csv (external, partial path); extended: GT-extended.csv (whole "
        "path, from scan matching); none",
    )
    laser: Literal["sick_front", "sick_rear", "hokuyo_front", "hokuyo_rear"] = option(
        "sick_front", "the primary laser (the others are kept beside it)"
    )


@dataclass(frozen=True)
class RawseedsWriteOptions(FormatOptions):
    """Writing a Rawseeds session."""

    session: str = option("Sim_2026-01-01a", "session name: the files' prefix")
    odometry_decimals: int = option(3, "decimals of odometry x, y, theta")
    chunk: int = option(20000, "scans formatted per block", positive=True)


@register
class Rawseeds(Importer[RawseedsOptions, RawseedsWriteOptions]):
    name: ClassVar[str] = "rawseeds"
    summary: ClassVar[str] = (
        "Rawseeds session dir or files: <session>-SICK_FRONT.csv(.bz2), -ODOMETRY_XYT, -GROUNDTRUTH ..."
    )
    Options = RawseedsOptions
    WriteOptions = RawseedsWriteOptions

    def sniff(self, path: Path) -> bool:
        path = Path(path)
        if path.is_dir():
            try:
                return any(classify(p) is not None for p in path.iterdir() if p.is_file())
            except OSError:
                return False
        if classify(path) is not None:
            return True
        line = head_bytes(path, 8192).split(b"\n", 1)[0].strip()
        return _looks_like_sick_line(line)

    def read(self, sources: Sequence[Path], options: RawseedsOptions) -> Dataset:
        """Import into a temporary dataset and load it (for small inputs and round trips)."""
        with tempfile.TemporaryDirectory(prefix="rawseeds-") as tmp:
            out = Path(tmp) / "ds"
            self.import_to(sources, out, options)
            ds = load(out)
            ds.path = None
        return ds

    def import_to(
        self, sources: Sequence[Path], out: Path, options: RawseedsOptions, force: bool = False
    ) -> Path:
        session = find_session([Path(s) for s in sources])
        gt_choice = options.groundtruth
        spec = LASERS[options.laser]
        if spec.stream not in session.files:
            raise FormatError(f"no {spec.stream} csv in {session.where}{_what_is_there(session)}")
        with atomic_dir(out, force=force) as tmp:
            meta = self._import(session, spec, gt_choice, tmp)
            (tmp / META).write_text(json.dumps(meta, indent=2, allow_nan=False) + "\n")
        return out

    def _import(
        self, session: Session, spec: LaserSpec, gt_choice: str, tmp: Path
    ) -> dict[str, Any]:
        report = ImportReport()
        files = session.files
        # sha256 of every source on a thread of its own, while the lasers are parsed
        stop = threading.Event()
        hasher = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="rawseeds-sha256")
        hashes = hasher.submit(_source_entries, list(files.values()), stop)
        hasher.shutdown(wait=False)
        try:
            return self._import_streams(session, spec, gt_choice, tmp, report, hashes)
        finally:
            stop.set()  # after a failure, stop hashing at once

    def _import_streams(
        self,
        session: Session,
        spec: LaserSpec,
        gt_choice: str,
        tmp: Path,
        report: ImportReport,
        hashes: concurrent.futures.Future[list[dict[str, Any]]],
    ) -> dict[str, Any]:
        files = session.files
        primary = stream_laser(files[spec.stream], spec, tmp / SCANS, report)
        report.records_read, report.records_kept = primary.rows_read, primary.rows_kept
        readings = {spec.name: _readings(primary)}
        lasers: dict[str, LaserGeometry] = {}
        for other in LASERS.values():
            if other is spec or other.stream not in files:
                continue
            res = stream_laser(
                files[other.stream],
                other,
                tmp / f"scans-{other.name}.parquet",
                report,
                f"{other.name}: ",
            )
            lasers[other.name] = _with_offset(other, res)
            readings[other.name] = _readings(res)

        if any(LASERS[n].stream in files for n in ("hokuyo_front", "hokuyo_rear")):
            report.note("Hokuyo mounting is not documented: x = y = z = 0, yaw 0 front / pi rear")
        if "ODOMETRY_XYT" in files:
            odo = read_pose_stream(files["ODOMETRY_XYT"], 7, (0, 4, 5, 6), report, "odometry: ")
            odo = plausible_poses(odo, report, "odometry")  # type: ignore[assignment]
            write_poses(tmp / ODOMETRY, odo)
        else:
            report.note("no ODOMETRY_XYT file: imported without odometry")

        gt_files = {"floor": "GROUNDTRUTH", "extended": "GT-extended"}
        gt_meta: dict[str, Any] = {"choice": gt_choice}
        for choice, stream in gt_files.items():
            if stream not in files:
                continue
            ncols = POSE_STREAMS[stream]
            poses = read_pose_stream(files[stream], ncols, (0, 1, 2, 3), report, f"{stream}: ")
            poses = plausible_poses(poses, report, stream)  # type: ignore[assignment]
            if choice == gt_choice:
                write_poses(tmp / GROUNDTRUTH, poses)
                gt_meta["file"] = files[stream].name
            else:
                write_poses(tmp / f"poses-gt-{choice}.parquet", poses)
        gt_meta["frame"] = {
            "floor": "floor frame of the ground-truth area (external cameras and lasers); "
            "covers only part of the path",
            "extended": "frame of the first robot pose; whole path; from scan matching on the "
            "robot's own lasers (not independent of them)",
            "none": "not imported",
        }[gt_choice]
        if gt_choice != "none" and "file" not in gt_meta:
            report.note(f"no {gt_files[gt_choice]} file: imported without ground truth")
        if "GROUNDTRUTH-CARTOGRAPHER" in files:
            carto = read_pose_stream(
                files["GROUNDTRUTH-CARTOGRAPHER"], 4, (0, 1, 2, 3), report, "cartographer: "
            )
            write_poses(tmp / "poses-cartographer.parquet", carto)
            report.note(
                "GROUNDTRUTH-CARTOGRAPHER is a SLAM estimate: kept as poses-cartographer, not as ground truth"
            )
        relations_meta: dict[str, Any] | None = None
        if "relations" in files:
            rows = read_rows(files["relations"], 8, report, "relations: ")
            table = pa.table({c: rows[:, i] for i, c in enumerate(RELATION_COLUMNS)})
            pq.write_table(table, tmp / RELATIONS, compression="zstd")
            relations_meta = {
                "file": files["relations"].name,
                "table": RELATIONS,
                "pairs": len(rows),
                "meaning": "pose of t2 in the frame of the pose at t1 (x, y, z m; roll, pitch, yaw rad)",
            }
        total = sum(r["total"] for r in readings.values())
        if total:
            lost = sum(r["no_return"] + r["invalid"] for r in readings.values())
            report.note(f"{lost} of {total} range readings are NaN (no return or invalid)")
        meta = make_meta(
            "rawseeds",
            [],
            _with_offset(spec, primary),
            report,
            lasers=lasers,
            session=session.name,
            scans=primary.rows_kept,
            beams=spec.geometry.beams,
            range_readings=readings,
            rawseeds={
                "primary_laser": spec.name,
                "streams": {k: v.name for k, v in sorted(files.items())},
                "groundtruth": gt_meta,
                "relations": relations_meta,
                "no_return": "SICK: readings >= 81.83 m (LMS error codes 8183..8191 cm) or 0 -> NaN; "
                "Hokuyo: < 0.02 m or > 5.6 m -> NaN; NaN, inf, negative -> NaN",
                "angular_offset": {f"{k:g}": v for k, v in sorted(primary.offsets.items())},
            },
        )
        meta["source"]["files"] = hashes.result()
        return meta

    def write(
        self, ds: Dataset, out: Path, options: RawseedsWriteOptions | None = None
    ) -> list[Path]:
        o = options or RawseedsWriteOptions()
        return write(
            ds, out, session=o.session, odometry_decimals=o.odometry_decimals, chunk=o.chunk
        )


def _source_entries(paths: Sequence[Path], stop: threading.Event) -> list[dict[str, Any]]:
    """Like toolkit.dataset.source_entries (path, bytes, sha256), but stops when told to."""
    entries = []
    for p in sorted(set(paths)):
        h = hashlib.sha256()
        with open(p, "rb") as f:
            while (block := f.read(1 << 22)) and not stop.is_set():
                h.update(block)
        entries.append({"path": str(p), "bytes": p.stat().st_size, "sha256": h.hexdigest()})
    return entries


def _readings(res: LaserResult) -> dict[str, int]:
    return {"total": res.readings, "no_return": res.no_return, "invalid": res.invalid}


def _with_offset(spec: LaserSpec, res: LaserResult) -> LaserGeometry:
    """The geometry, with angle_min moved by the most common angular_offset (in 1/4 degree)."""
    if not res.offsets:
        return spec.geometry
    offset = max(res.offsets.items(), key=lambda kv: kv[1])[0]
    if offset == 0:
        return spec.geometry
    g = spec.geometry.to_dict()
    g["angle_min"] = spec.geometry.angle_min + math.radians(offset / 4.0)
    return LaserGeometry.from_dict(g)


# ---------------------------------------------------------------- writer


def fixed_text(values: np.ndarray, decimals: int) -> pa.Array:
    """Numbers as fixed-point text ('%.{decimals}f'), vectorised through a decimal cast."""
    arr = pa.array(np.asarray(values, dtype=np.float64))  # the cast rounds half away from 0
    return pc.cast(pc.cast(arr, pa.decimal128(18 + decimals, decimals), safe=False), pa.string())


def _write_lines(path: Path, columns: Sequence[pa.Array]) -> None:
    lines = pc.binary_join_element_wise(*columns, ",")
    text = "\n".join(lines.to_pylist())
    with atomic_file(path) as tmp:
        tmp.write_text(text + "\n" if text else "")


def write(
    ds: Dataset,
    out: str | Path,
    session: str = "Sim_2026-01-01a",
    odometry_decimals: int = 3,
    chunk: int = 20000,
) -> list[Path]:
    """Write `ds` as a Rawseeds session under `out`: SICK_FRONT (the primary laser, which must be
    181 beams at 1°), ODOMETRY_XYT (ticks 0) and GROUNDTRUTH (zero covariance) when present.
    t with 6 decimals, ranges with 3 (as Rawseeds), NaN as 81.910; odometry x, y, theta with
    `odometry_decimals` (3, as the Rawseeds odometry example line), ground truth with 6."""
    out = Path(out)
    g = ds.laser
    if ds.n_beams != 181 or abs(g.angle_increment - math.radians(1.0)) > 1e-9:
        raise ToolkitError(
            f"Rawseeds SICK_FRONT needs 181 beams at 1 deg; the dataset has {ds.n_beams} at "
            f"{math.degrees(g.angle_increment):.4g} deg"
        )
    out.mkdir(parents=True, exist_ok=True)
    written = []
    laser_path = out / f"{session}-SICK_FRONT.csv"
    with atomic_file(laser_path) as tmp, open(tmp, "w") as f:
        for start in range(0, ds.n_scans, chunk):
            t = ds.t[start : start + chunk]
            r = ds.ranges[start : start + chunk]
            r = np.where(np.isfinite(r) & (r < SICK_RANGE_MAX) & (r > 0), r, SICK_NO_RETURN)
            f.write(sick_lines(t, r))
    written.append(laser_path)
    if ds.odometry is not None:
        odo = ds.odometry
        n = len(odo)
        path = out / f"{session}-ODOMETRY_XYT.csv"
        cols = [
            fixed_text(odo["t"].to_numpy(), 6),
            pa.array([str(i % 65536) for i in range(n)]),
            pa.array(["0"] * n),
            pa.array(["0"] * n),
        ] + [fixed_text(odo[c].to_numpy(), odometry_decimals) for c in ("x", "y", "theta")]
        _write_lines(path, cols)
        written.append(path)
    if ds.groundtruth is not None:
        gt = ds.groundtruth
        path = out / f"{session}-GROUNDTRUTH.csv"
        zero = pa.array(["0.000000"] * len(gt))
        cols = [fixed_text(gt[c].to_numpy(), 6) for c in ("t", "x", "y", "theta")] + [zero] * 9
        _write_lines(path, cols)
        written.append(path)
    return written


def sick_lines(t: np.ndarray, ranges: np.ndarray) -> str:
    """'t,181,0,R1,...,R181' lines, built column-wise by pyarrow (no loop per scan or beam)."""
    rows, beams = ranges.shape
    if rows == 0:
        return ""
    flat = fixed_text(ranges.reshape(-1), 3)
    offsets = pa.array(np.arange(0, rows * beams + 1, beams, dtype=np.int32))
    per_row = pc.binary_join(pa.ListArray.from_arrays(offsets, flat), ",")
    head = pa.scalar(f"{beams},0")
    lines = pc.binary_join_element_wise(fixed_text(t, 6), head, per_row, ",")
    return "\n".join(lines.to_pylist()) + "\n"
