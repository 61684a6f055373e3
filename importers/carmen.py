"""CARMEN logs (`carmen`): FLASER/RLASER, ROBOTLASER1/2, ODOM, TRUEPOS, PARAM; DP-SLAM logs.

Reading, and the decisions a log leaves open (each is stated in meta.json and the report):

- Lasers. FLASER (front) and RLASER (rear) are the old format without angles: the beam count
  fixes the layout (181 = 180° at 1° from -90°, 180 = 179° at 1° from -90°, 361 = 180° at
  0.5°, 360 = 179.5° at 0.5°, 401 = 100° at 0.25° centred, -50°; any other count: 180° from
  -90°, noted). ROBOTLASER1/2 carry start_angle, fov, resolution and max_range. DP-SLAM
  (`Odometry x y th` / `Laser n r...`, no clock) pairs each Laser with the Odometry before it.
  The primary laser is FLASER, else ROBOTLASER1, else Laser, else RLASER, else ROBOTLASER2
  (`--laser NAME` picks another); the others become further lasers named after the message.
- Damage is local and skipped, counted with the first line it was seen on: a wrong number of
  ranges or fields (a truncated last line has its own reason), a non-numeric value in a line,
  a beam count other than the log's majority, a scan whose timestamp goes backwards (the team
  default: drop it, keep file order). An empty file, a file with no laser lines, or one whose
  laser lines are all damaged is an error naming the file.
- No-return codes. Values at the top of a log's range (81.91, 81.83, 51.15, 32.767, 8.191,
  7.999 ...) are the scanner's "no return": the largest value that recurs at least
  `CODE_MIN_COUNT` times is the code, it becomes `range_max`, and every value within
  `CODE_BAND` below it or above becomes NaN. ROBOTLASER max_range, the writer's PARAM
  `toolkit_laser_range_max` or `-O range_max=X` set the code explicitly (`-O range_max=none`
  turns the detection off). NaN, inf and negative values in the file become NaN too (counted).
- Clock. Scans take the message timestamp. A log without timestamps (CSM, DP-SLAM), or whose
  timestamps are broken (fewer than half distinct: all 0, printed with too few digits; or more
  than a quarter out of order: garbage), falls back to scan order: t = index / rate, rate from
  `--rate` or 1 Hz nominal; meta["time_source"] = "scan_order".
- Odometry: the ODOM stream at its own times when the log has a usable clock (lines out of
  order are dropped and counted, the fewest that restore the order: one stray timestamp costs
  one line; the Radish logs have an ODOM line stamped 0 after each FLASER); otherwise the
  robot (odometry) pose of each laser line at scan times. Ground truth: TRUEPOS lines. `-O poses=groundtruth` stores the laser lines' robot
  poses as ground truth instead (the Radish "corrected" logs: SLAM-corrected poses used as
  approximate truth); where every line's laser and robot poses are equal although the laser
  is mounted off centre (a corrector wrote its scan pose into both), they are taken as the
  laser's poses and the truth as the robot's behind them (laser pose ∘ mounting⁻¹; the
  default since session 34, `-O equal_poses=robot` the old reading: docs/journal/maps.md,
  sessions 33 and 34). A raw log (poses differing, or the laser at the centre) is untouched. Laser lines' robot poses that are neither odometry nor ground truth are
  kept as the pose stream `scan_pose`.
- Mounting: x from PARAM robot_frontlaser_offset (robot_rearlaser_offset for the rear laser),
  y and yaw (and x when there is no PARAM) from the median difference between the laser pose
  and the robot pose of the laser lines, in the robot frame.

Writing (`write`): PARAM lines, ODOM from ds.odometry, FLASER (old layouts) or ROBOTLASER1
(anything else) with the laser pose and the odometry pose interpolated at scan times, TRUEPOS
from ds.groundtruth; timestamps with 6 decimals, ranges with 3 (mm), NaN as the range_max code.
"""

from __future__ import annotations

import bisect
import json
import math
import re
from array import array
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd
from rich.progress import TaskID

from importers import register
from importers.base import (
    FormatOptions,
    Importer,
    RowSpill,
    TextBlocks,
    head_bytes,
    option,
    write_pose_blocks,
)
from toolkit import se2
from toolkit.atomic import atomic_dir, atomic_file
from toolkit.dataset import (
    FORMAT_VERSION,
    GROUNDTRUTH,
    META,
    ODOMETRY,
    SCANS,
    Dataset,
    ImportReport,
    LaserGeometry,
    PoseStream,
    Scans,
    ScansWriter,
    check_scans,
    make_meta,
    plausible_poses,
    pose_frame,
    write_poses,
)
from toolkit.errors import FormatError, ToolkitError
from toolkit.progress import task

#: a value is a no-return code if it is the largest one recurring at least this often
CODE_MIN_COUNT = 5
#: values this fraction below the detected code, or above it, are no-returns too
CODE_BAND = 0.005
#: timestamps are broken if fewer than this fraction are distinct ...
MIN_DISTINCT = 0.5
#: ... or more than this fraction are out of order
MAX_OUT_OF_ORDER = 0.25
NOMINAL_RATE = 1.0
CONVERT_ROWS = 512  # laser lines whose tokens are held before converting them in one call
POSE_BLOCK = 1 << 16  # ODOM/TRUEPOS lines whose values are held before they are spilled
POSE_GROUP = 1 << 17  # poses per Parquet row group when streamed (write_table: up to 1 Mi)
MAX_PARAMS = 1000  # distinct PARAM names and other words kept (a garbage file has millions)

#: old-format beam layouts: beams -> (first angle, step), degrees
OLD_LAYOUTS: dict[int, tuple[float, float]] = {
    181: (-90.0, 1.0),
    180: (-90.0, 1.0),
    361: (-90.0, 0.5),
    360: (-90.0, 0.5),
    401: (-50.0, 0.25),
}
OLD_LASERS = ("FLASER", "RLASER")
NEW_LASERS = ("ROBOTLASER1", "ROBOTLASER2")
DPSLAM_LASER = "Laser"
PRIMARY_ORDER = ("FLASER", "ROBOTLASER1", DPSLAM_LASER, "RLASER", "ROBOTLASER2")
REAR = ("RLASER", "ROBOTLASER2")
CARMEN_TOKENS = frozenset(
    {"FLASER", "RLASER", "ROBOTLASER1", "ROBOTLASER2", "ODOM", "TRUEPOS", "PARAM", "SYNC", "NEFF"}
    | {f"RAWLASER{i}" for i in range(1, 5)}
)
DPSLAM_TOKENS = frozenset({"odometry", "laser"})
RANGE_PARAM = "toolkit_laser_range_max"
_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^[-+]?(nan|inf)$", re.IGNORECASE)


class _Drops:
    """Damaged lines by reason: how many, the first and the last one (file order), so that
    a log of millions of damaged lines costs a few numbers, not a list."""

    def __init__(self) -> None:
        self.count: dict[str, int] = {}
        self.first: dict[str, int] = {}
        self.last: dict[str, int] = {}

    def add(self, reason: str, numbers: np.ndarray | int) -> None:
        arr = np.atleast_1d(np.asarray(numbers, dtype=np.int64))
        if not arr.size:
            return
        self.count[reason] = self.count.get(reason, 0) + int(arr.size)
        self.first[reason] = min(self.first.get(reason, int(arr.min())), int(arr.min()))
        self.last[reason] = max(self.last.get(reason, 0), int(arr.max()))

    def merge(self, other: _Drops) -> None:
        for reason, count in other.count.items():
            self.count[reason] = self.count.get(reason, 0) + count
            self.first[reason] = min(self.first.get(reason, other.first[reason]),
                                     other.first[reason])  # fmt: skip
            self.last[reason] = max(self.last.get(reason, 0), other.last[reason])

    def report(self, report: ImportReport, path: Path, last_line: int) -> None:
        """Into `report`, first-seen first; the unterminated last line (`last_line`) under
        its own reason, unless the reason is a value's or a beam count's."""
        for reason in sorted(self.count, key=self.first.__getitem__):
            count, first = self.count[reason], self.first[reason]
            exempt = reason.endswith("non-numeric value") or reason.startswith("beam count")
            if last_line and self.last[reason] == last_line and not exempt:
                count -= 1
                report.drop("truncated last line", 1, _where(path, last_line))
            if count:
                report.drop(reason, count, _where(path, first))


@dataclass
class _LayoutRows:
    """A laser message's lines of one layout: their numbers, positions among the message's
    lines, and their numeric fields converted in blocks (the tokens are not kept); the ranges
    of the lines whose fields are numbers go to a `RowSpill` (on disk for `import_to`)."""

    cols: np.ndarray  # token columns of the fields, see `_columns`; the ranges' first
    beams: int  # ranges: the first `beams` fields, kept as float32 (converted via float64)
    where: Path | None = None  # where the ranges spill (None: kept in memory)
    numbers: array = field(default_factory=lambda: array("q"))
    index: array = field(default_factory=lambda: array("q"))
    ok: bytearray = field(default_factory=bytearray)  # per line: its fields are numbers
    pending: list[list[str]] = field(default_factory=list)
    rest: list[np.ndarray] = field(default_factory=list)  # ok lines' other fields, float64
    ranges: RowSpill = field(init=False)  # ok lines' ranges, float32

    def __post_init__(self) -> None:
        self.ranges = RowSpill(self.beams, np.float32, self.where)

    def add(self, number: int, index: int, tokens: list[str]) -> None:
        lo, hi = int(self.cols.min()), int(self.cols.max()) + 1
        self.numbers.append(number)
        self.index.append(index)
        self.pending.append(tokens[lo:hi])
        if len(self.pending) >= CONVERT_ROWS:
            self.flush()

    def flush(self) -> None:
        if not self.pending:
            return
        cols = self.cols - self.cols.min()
        try:
            values = np.array(self.pending, dtype=np.float64)[:, cols]
            self.ok.extend(b"\x01" * len(self.pending))
        except ValueError:  # find the damaged lines, only on this slow path
            good = []
            for row in self.pending:
                try:
                    good.append(np.array(row, dtype=np.float64)[cols])
                    self.ok.append(1)
                except ValueError:
                    self.ok.append(0)
            values = np.array(good).reshape(len(good), cols.size)
        self.ranges.append(values[:, : self.beams].astype(np.float32))
        self.rest.append(values[:, self.beams :].copy())
        self.pending = []


@dataclass
class _LaserLines:
    """One laser message's lines: per layout (beams, remissions, clock) the converted
    fields; lines whose layout cannot be told, by reason."""

    count: int = 0
    layouts: dict[tuple[int, int, bool], _LayoutRows] = field(default_factory=dict)
    bad: _Drops = field(default_factory=_Drops)
    where: Path | None = None  # where the ranges spill (None: kept in memory)

    def add(self, msg: str, number: int, tokens: list[str]) -> None:
        lay = _layout(msg, tokens)
        if isinstance(lay, str):
            self.bad.add(lay, number)
        else:
            rows = self.layouts.get(lay)
            if rows is None:
                cols = _columns(msg, *lay)
                flat = np.concatenate([cols[k] for k in _FIELDS if k in cols])
                rows = self.layouts[lay] = _LayoutRows(flat, lay[0], self.where)
            rows.add(number, self.count, tokens)
        self.count += 1


@dataclass
class _PoseLines:
    """ODOM or TRUEPOS lines: x, y, theta and timestamp of those with 10 fields. The four
    values go to a `RowSpill` (on disk for `import_to`) every `POSE_BLOCK` lines; what the
    stream's order is decided on stays: timestamps, line numbers, finite or not."""

    count: int = 0
    seven: int = 0  # lines of 7 fields (no timestamp)
    where: Path | None = None  # where the values spill (None: kept in memory)
    stamps: array = field(default_factory=lambda: array("d"))  # of the flushed lines
    finite: bytearray = field(default_factory=bytearray)  # per flushed line: 4 finite values
    pending: array = field(default_factory=lambda: array("d"))  # 5 per line, not yet flushed
    values: RowSpill = field(init=False)  # x, y, theta, timestamp, line number per line
    wrong: list[int] = field(default_factory=list)  # first and last line without 10 fields
    wrong_count: int = 0
    non_numeric: list[int] = field(default_factory=list)

    def add(self, number: int, tokens: list[str]) -> None:
        self.count += 1
        self.seven += len(tokens) == 7
        if len(tokens) != 10:
            if len(self.wrong) < 2:  # the first and the last are what the report needs
                self.wrong.append(number)
            else:
                self.wrong[-1] = number
            self.wrong_count += 1
            return
        try:
            fields = [float(tokens[i]) for i in (1, 2, 3, 7)]
        except ValueError:
            self.non_numeric.append(number)
            return
        self.pending.extend(fields)
        self.pending.append(number)
        if len(self.pending) >= 5 * POSE_BLOCK:
            self.flush()

    def __post_init__(self) -> None:
        self.values = RowSpill(5, np.float64, self.where)

    def flush(self) -> None:
        if not self.pending:
            return
        block = np.array(self.pending, dtype=np.float64).reshape(-1, 5)
        self.pending = array("d")
        self.values.append(block)
        self.stamps.frombytes(block[:, 3].tobytes())
        self.finite.extend(np.isfinite(block[:, :4]).all(axis=1).tobytes())

    def number(self, row: int) -> int:
        """The line number of the `row`-th line with 10 numeric fields."""
        return int(self.values.row(row)[4])


@dataclass
class _Lines:
    """The data lines of a log, by message, converted as they are read; the rest counted."""

    where: Path | None = None  # where converted values spill (None: kept in memory)
    lasers: dict[str, _LaserLines] = field(default_factory=dict)
    odom: _PoseLines = field(init=False)
    truepos: _PoseLines = field(init=False)
    params: dict[str, list[str]] = field(default_factory=dict)
    skipped: Counter[str] = field(default_factory=Counter)
    dpslam_odometry: int = 0  # DP-SLAM Odometry lines, all
    bad: list[tuple[str, int]] = field(default_factory=list)  # (reason, line) of damaged ones
    stream_error: str | None = None  # the compressed stream ended early
    last_line: int = 0  # number of the last line, if it lacks its newline (else 0)

    def __post_init__(self) -> None:
        self.odom = _PoseLines(where=self.where)
        self.truepos = _PoseLines(where=self.where)

    def laser(self, msg: str) -> _LaserLines:
        lines = self.lasers.get(msg)
        if lines is None:
            lines = self.lasers[msg] = _LaserLines(where=self.where)
        return lines


@dataclass
class _LaserStream:
    """One laser's kept lines, parsed."""

    name: str
    lines: np.ndarray  # (S,) line numbers
    index: np.ndarray  # (S,) position among this laser's lines in the file (for scan order)
    ranges: RowSpill  # float32 rows (parsed as float64, as the file's text), S of them kept:
    rows: np.ndarray  # the kept rows of `ranges` (S of them True)
    laser_pose: np.ndarray  # (S, 3)
    robot_pose: np.ndarray  # (S, 3)
    stamp: np.ndarray | None  # (S,) message timestamps, None without a clock
    header: np.ndarray | None  # ROBOTLASER: (S, 4) start_angle, fov, resolution, max_range
    read: int  # lines of this message in the file


# ---------------------------------------------------------------- reading lines


def _split_lines(path: Path, where: Path | None = None) -> _Lines:
    """One pass over the file in blocks (bounded memory: `TextBlocks`): every data line
    filed under its message, laser and pose fields converted to numbers as they come (and,
    with `where`, spilled there)."""
    out = _Lines(where)
    reader = TextBlocks(path)
    number = 0
    seen_text = False
    dpslam_pose: list[str] | None = None
    size = path.stat().st_size
    with task(f"reading {path.name}", total=size) as (bar, job):
        for block in reader:
            seen_text = seen_text or bool(block.strip())
            for line in block.splitlines():
                number += 1
                dpslam_pose = _sort_line(out, number, line, dpslam_pose)
            bar.update(TaskID(job), completed=min(size, reader.bytes))
    for laser in out.lasers.values():
        for rows in laser.layouts.values():
            rows.flush()
    out.odom.flush()
    out.truepos.flush()
    out.stream_error = reader.error
    if not seen_text:
        raise FormatError("empty file", file=path)
    if reader.unterminated:
        out.last_line = number
    return out


def _sort_line(
    out: _Lines, number: int, line: str, dpslam_pose: list[str] | None
) -> list[str] | None:
    """File one line under its message; returns the DP-SLAM Odometry pose now in force."""
    tokens = line.split()
    if not tokens or tokens[0].startswith("#"):
        return dpslam_pose
    msg = tokens[0]
    if msg in OLD_LASERS or msg in NEW_LASERS:
        out.laser(msg).add(msg, number, tokens)
    elif msg == "ODOM":
        out.odom.add(number, tokens)
    elif msg == "TRUEPOS":
        out.truepos.add(number, tokens)
    elif msg == "PARAM":
        if len(tokens) >= 3 and len(out.params) < MAX_PARAMS:
            values = out.params.setdefault(tokens[1], [])
            if len(values) < MAX_PARAMS:
                values.append(tokens[2])
    elif msg.lower() == "odometry":
        out.dpslam_odometry += 1
        dpslam_pose = tokens[1:4] if len(tokens) == 4 else None
        if dpslam_pose is None:
            out.bad.append(("Odometry wrong number of fields", number))
    elif msg.lower() == "laser":
        # as an old-format laser line without clock: laser pose = robot pose = Odometry
        pose = dpslam_pose if dpslam_pose is not None else ["nan"] * 3
        out.laser(DPSLAM_LASER).add(DPSLAM_LASER, number, tokens + pose + pose)
    else:
        if msg in out.skipped or len(out.skipped) < MAX_PARAMS:
            out.skipped[msg] += 1
        else:
            out.skipped["(other words)"] += 1
    return dpslam_pose


def _layout(msg: str, tokens: list[str]) -> tuple[int, int, bool] | str:
    """(beams, remissions, has clock) of a laser line, or why it is damaged."""
    try:
        if msg in NEW_LASERS:
            n = int(tokens[8])
            m = int(tokens[9 + n])
            fixed = 21 + n + m  # header 9, count m 1, poses 6, tv rv safety 5
        else:
            n, m = int(tokens[1]), 0
            fixed = 8 + n
    except ValueError:
        return "non-numeric value"
    except IndexError:
        return "wrong number of ranges"
    if n < 1 or m < 0:
        return "wrong number of ranges"
    if len(tokens) == fixed:
        return n, m, False
    if len(tokens) == fixed + 3:
        return n, m, True
    return "wrong number of ranges"


def _columns(msg: str, n: int, m: int, clock: bool) -> dict[str, np.ndarray]:
    """Token columns of a laser line's fields."""
    if msg in NEW_LASERS:
        ranges = 9 + np.arange(n)
        poses = 10 + n + m + np.arange(6)
        header = np.arange(2, 6)
        stamp = 21 + n + m
    else:
        ranges = 2 + np.arange(n)
        poses = 2 + n + np.arange(6)
        header = np.arange(0)
        stamp = 8 + n
    cols = {"ranges": ranges, "poses": poses, "header": header}
    if clock:
        cols["stamp"] = np.array([stamp])
    return cols


_FIELDS = ("ranges", "poses", "header", "stamp")


def _where(path: Path, line: int) -> str:
    return f"{path}:{line}"


def _parse_laser(
    path: Path, msg: str, lines: _LaserLines, last_line: int, report: ImportReport
) -> _LaserStream | None:
    """Keep the lines of the log's majority layout (their fields were converted while
    reading); count the others by reason."""
    drops = _Drops()
    drops.merge(lines.bad)
    if not lines.layouts:
        drops.report(report, path, last_line)
        return None
    counts = Counter({lay: len(rows.numbers) for lay, rows in lines.layouts.items()})
    main = counts.most_common(1)[0][0]
    n, m, clock = main
    for lay, rows in lines.layouts.items():
        if lay != main:
            why = f"beam count {lay[0]} (the log's is {n})" if lay[0] != n else (
                "wrong number of fields")  # fmt: skip
            drops.add(why, np.frombuffer(rows.numbers, dtype=np.int64))
            rows.ranges.close()
            rows.rest = []
    rows = lines.layouts[main]
    ok = np.frombuffer(bytes(rows.ok), dtype=np.uint8).astype(bool)
    numbers = np.frombuffer(rows.numbers, dtype=np.int64)
    drops.add("non-numeric value", numbers[~ok])
    drops.report(report, path, last_line)
    if not ok.any():
        return None
    cols = _columns(msg, n, m, clock)
    # the other fields in arrays of their own (the ranges stay where they are)
    sizes = {k: cols[k].size for k in _FIELDS if k in cols and k != "ranges"}
    rest = np.concatenate(rows.rest) if rows.rest else np.empty((0, sum(sizes.values())))
    rows.rest = []
    parts, col = {}, 0
    for k, size in sizes.items():
        parts[k] = rest[:, col : col + size]
        col += size
    return _LaserStream(
        name=msg,
        lines=numbers[ok],
        index=np.frombuffer(rows.index, dtype=np.int64)[ok],
        ranges=rows.ranges,
        rows=np.ones(rows.ranges.rows, dtype=bool),
        laser_pose=parts["poses"][:, :3],
        robot_pose=parts["poses"][:, 3:],
        stamp=parts["stamp"][:, 0] if clock else None,
        header=parts["header"] if msg in NEW_LASERS else None,
        read=lines.count,
    )


def _reason(reason: str, line: int, last_line: int) -> str:
    if line == last_line and reason != "non-numeric value":
        return "truncated last line"
    return reason


# ---------------------------------------------------------------- decisions


def broken_clock(stamp: np.ndarray, kept: np.ndarray | None = None) -> str | None:
    """Why a stream's timestamps cannot serve as a clock, or None if they can; `kept` marks
    the stamps that stay in order (default: those not below an earlier one)."""
    if stamp.size < 2:
        return None
    if not np.isfinite(stamp).all():
        return "non-finite timestamps"
    distinct = np.unique(stamp).size
    if distinct < MIN_DISTINCT * stamp.size:
        return f"only {distinct} distinct timestamps in {stamp.size} (all 0, or too few digits)"
    late = int((~(in_order(stamp) if kept is None else kept)).sum())
    if late > MAX_OUT_OF_ORDER * stamp.size:
        return f"{late} of {stamp.size} timestamps out of order"
    return None


def in_order(stamp: np.ndarray) -> np.ndarray:
    """True where a timestamp is not below any earlier one (the rest are dropped)."""
    if stamp.size == 0:
        return np.zeros(0, dtype=bool)
    before = np.maximum.accumulate(np.concatenate([[-np.inf], stamp[:-1]]))
    return stamp >= before


def longest_in_order(stamp: np.ndarray) -> np.ndarray:
    """True on a longest non-decreasing subsequence: the fewest lines dropped to restore order
    (a pose stream's stray timestamp, early or late, costs one line, not all lines after it)."""
    if stamp.size < 2 or bool(np.all(np.diff(stamp) >= 0)):
        return np.ones(stamp.size, dtype=bool)
    tails: list[float] = []  # smallest last stamp of an in-order run of each length
    ends: list[int] = []  # index of that last stamp
    before = np.full(stamp.size, -1)
    for i, value in enumerate(stamp.tolist()):  # sequential by nature; bisect keeps it O(n log n)
        j = bisect.bisect_right(tails, value)
        if j == len(tails):
            tails.append(value)
            ends.append(i)
        else:
            tails[j], ends[j] = value, i
        before[i] = ends[j - 1] if j else -1
    keep = np.zeros(stamp.size, dtype=bool)
    i = ends[-1] if ends else -1
    while i >= 0:
        keep[i] = True
        i = before[i]
    return keep


def no_return_code(ranges: np.ndarray) -> float | None:
    """The largest value recurring at least CODE_MIN_COUNT times: the scanner's no-return code."""
    values = _Values()
    for block in _row_blocks(ranges):  # a log's distinct values are few: mm steps
        values.add(block[np.isfinite(block)])
    return values.code()


class _Values:
    """The distinct values of a laser's ranges with their counts, gathered block by block
    (a log's distinct values are few: mm steps), so that no copy of the whole log is sorted."""

    def __init__(self) -> None:
        self.parts: list[tuple[np.ndarray, np.ndarray]] = []
        self.uniq: np.ndarray = np.empty(0, np.float32)
        self.counts: np.ndarray = np.empty(0, np.float64)

    def add(self, finite: np.ndarray) -> None:
        if finite.size:
            self.parts.append(np.unique(finite, return_counts=True))
        if len(self.parts) >= 16:
            self.merge()

    def merge(self) -> None:
        if not self.parts:
            return
        self.parts.append((self.uniq, self.counts))
        uniq, inverse = np.unique(np.concatenate([u for u, _ in self.parts]), return_inverse=True)
        self.counts = np.bincount(inverse, weights=np.concatenate([c for _, c in self.parts]))
        self.uniq, self.parts = uniq, []

    def code(self) -> float | None:
        """The largest value recurring at least CODE_MIN_COUNT times."""
        self.merge()
        frequent = self.uniq[self.counts >= CODE_MIN_COUNT]
        return _as_printed(frequent[-1]) if frequent.size else None

    def top(self) -> float:
        """The largest value, -inf if none."""
        self.merge()
        return self.uniq[-1] if self.uniq.size else -np.inf

    def at_least(self, code: float) -> int:
        """How many values are >= `code` (compared as the float32 ranges are)."""
        self.merge()
        return int(self.counts[self.uniq >= code].sum())


def _as_printed(value: float) -> float:
    """A float32 range as the decimal the log printed (81.91, not 81.91000366)."""
    return float(str(np.float32(value)))


def _row_blocks(a: np.ndarray, rows: int = 4096) -> Iterator[np.ndarray]:
    for lo in range(0, len(a), rows):
        yield a[lo : lo + rows]


def _laser_poses_carried(main: _Built) -> np.ndarray | None:
    """The robot's poses behind the laser lines' laser poses (laser pose ∘ mounting⁻¹) when
    every line's laser and robot poses are equal although the laser is mounted off the
    robot's centre: a corrector (GMapping's log writer: host pippo, NEFF lines) wrote one pose
    into both fields, and with the mounting the two fields cannot both be right. Radish's
    belgioioso, freiburg-101 and freiburg-campus (PARAM x -0.04 m): their scans, placed by
    those poses, agree best with the laser at the pose itself (turned revisits: peak at
    +0.002 / 0.000 / -0.007 m), so the pose is the laser's (docs/journal/maps.md, sessions
    32 to 34; `-O equal_poses=laser`, the default since session 34). None otherwise (the
    robot poses stand)."""
    laser, robot = main.stream.laser_pose, main.stream.robot_pose
    mount = se2.mount_pose(main.laser)
    if main.stream.name in REAR or not mount[:2].any():  # a rear laser's yaw pi is assumed
        return None
    if not len(laser) or not np.array_equal(laser, robot, equal_nan=True):
        return None
    robot = se2.compose(laser, np.broadcast_to(se2.inverse(mount), laser.shape))
    robot[:, 2] = laser[:, 2] - mount[2]  # the heading as the log has it (not wrapped)
    return robot


def _pose_frame(t: np.ndarray, pose: np.ndarray) -> pd.DataFrame:
    ok = np.isfinite(pose).all(axis=1)
    return pose_frame(t[ok], pose[ok])


def _param_float(lines: _Lines, name: str, report: ImportReport) -> float | None:
    values = lines.params.get(name)
    if not values:
        return None
    try:
        floats = [float(v) for v in values]
    except ValueError:
        report.note(f"PARAM {name} {values[-1]!r} is not a number; ignored")
        return None
    if len(set(floats)) > 1:
        report.note(f"PARAM {name} is given {len(floats)} times ({floats}); the last one is used")
    return floats[-1]


@dataclass
class _Built:
    """One laser, decided: times, geometry, the no-return code; its ranges are read from
    the stream's spill and cleaned block by block (`blocks`), or all at once (`ranges`)."""

    stream: _LaserStream
    t: np.ndarray
    laser: LaserGeometry
    code: float | None  # ranges at or above it become NaN
    time_source: str
    decisions: dict[str, Any]

    def blocks(self) -> Iterator[np.ndarray]:
        """The kept scans' ranges in order, cleaned (NaN, inf, negative and no-return -> NaN)."""
        code = self.code
        for block in self.stream.ranges.take(self.stream.rows):
            with np.errstate(invalid="ignore"):
                block[~np.isfinite(block) | (block < 0)] = np.nan
                if code is not None:
                    block[block >= code] = np.nan
            yield block

    def ranges(self) -> np.ndarray:
        parts = list(self.blocks())
        if not parts:
            return np.empty((0, self.laser.beams), np.float32)
        return np.concatenate(parts) if len(parts) > 1 else parts[0]

    def scans(self) -> Scans:
        return Scans(self.t, self.ranges(), self.laser)


@dataclass
class _SpilledPoses:
    """An ODOM or TRUEPOS stream: the kept `rows` (a mask) of its lines' x, y, theta, t."""

    values: RowSpill
    rows: np.ndarray

    def __len__(self) -> int:
        return int(np.count_nonzero(self.rows))

    def blocks(self) -> Iterator[np.ndarray]:
        """The kept poses block by block, as t, x, y, theta rows."""
        for block in self.values.take(self.rows, POSE_GROUP):
            yield block[:, [3, 0, 1, 2]]

    def frame(self) -> pd.DataFrame:
        parts = list(self.blocks())
        v = np.concatenate(parts) if parts else np.empty((0, 4))
        return pose_frame(v[:, 0], v[:, 1:])


_Poses = pd.DataFrame | _SpilledPoses


def _frame(poses: _Poses | None) -> pd.DataFrame | None:
    return poses.frame() if isinstance(poses, _SpilledPoses) else poses


@dataclass
class _Plan:
    """A log, decided: its lasers, pose streams and meta.json; the data still to be read."""

    main: _Built
    others: dict[str, _Built]  # further lasers by (lower-case) name
    odometry: _Poses | None
    groundtruth: _Poses | None
    poses: dict[str, _Poses]
    meta: dict[str, Any]

    def write(self, directory: Path) -> None:
        """The dataset's files, as `write_dataset_files` writes them, block by block: the
        ranges and poses in Parquet row groups as they are read from the spill."""
        meta = self.meta
        source = meta.get("source")
        report = ImportReport.from_dict(meta.get("import_report", {}))
        files = (source or {}).get("files") or [{}]
        origin = Path(files[0].get("path", "dataset"))  # what errors name
        lasers = [(SCANS, self.main)] + [(f"scans-{k}.parquet", b) for k, b in self.others.items()]
        for _, built in lasers:
            check_scans(built.t, None, origin)
        fixed = 0
        for name, built in lasers:
            with ScansWriter(directory / name, built.laser.beams, laser=built.laser,
                             source=source) as writer:  # fmt: skip
                at = 0
                for block in built.blocks():
                    fixed += check_scans(built.t[:0], block, origin)
                    writer.write(built.t[at : at + len(block)], block)
                    at += len(block)
        if fixed:
            report.note(f"{fixed} impossible range(s) (infinite, negative, > 1e6 m) set to NaN")
        streams = [(ODOMETRY, "odometry", self.odometry), (GROUNDTRUTH, "groundtruth",
                   self.groundtruth)] + [(f"poses-{k}.parquet", k, v) for k, v in self.poses.items()]  # fmt: skip
        for name, what, poses in streams:
            if poses is None:
                continue
            if isinstance(poses, _SpilledPoses):
                write_pose_blocks(directory / name, poses.blocks(), report, what)
            else:
                frame = plausible_poses(poses, report, what)
                assert frame is not None
                write_poses(directory / name, frame)
        meta["import_report"] = report.to_dict()
        meta.setdefault("format_version", FORMAT_VERSION)
        meta["laser"] = self.main.laser.to_dict()
        meta["lasers"] = {k: b.laser.to_dict() for k, b in self.others.items()}
        meta["scans"] = int(self.main.t.size)
        meta["beams"] = self.main.laser.beams
        (directory / META).write_text(json.dumps(meta, indent=2, allow_nan=False) + "\n")


class _Reader:
    """Turns the parsed lines of one log into a Dataset, recording each decision."""

    def __init__(self, path: Path, options: CarmenOptions, where: Path | None = None) -> None:
        self.path = path
        self.options = options
        self.report = ImportReport()
        self.lines = _split_lines(path, where)

    def dataset(self) -> Dataset:
        """The whole dataset in memory."""
        plan = self.plan()
        main = plan.main
        return Dataset(
            t=main.t,
            ranges=main.ranges(),
            laser=main.laser,
            odometry=_frame(plan.odometry),
            groundtruth=_frame(plan.groundtruth),
            meta=plan.meta,
            lasers={k: b.scans() for k, b in plan.others.items()},
            poses={k: f for k, v in plan.poses.items() if (f := _frame(v)) is not None},
        )

    def plan(self) -> _Plan:
        """Every decision and the report; the ranges and ODOM/TRUEPOS poses stay where they
        were put while reading (memory or spill) until they are written."""
        lines, report, path = self.lines, self.report, self.path
        if not lines.lasers:
            raise FormatError(
                "no laser lines (FLASER, RLASER, ROBOTLASER1/2 or DP-SLAM Laser) found", file=path
            )
        streams: dict[str, _LaserStream] = {}
        for msg, entries in lines.lasers.items():
            stream = _parse_laser(path, msg, entries, lines.last_line, report)
            if stream is not None:
                streams[msg] = stream
        read = sum(v.count for v in lines.lasers.values())
        if not streams:
            first = next(iter(report.examples.values()), "?")
            raise FormatError(f"no usable laser line: all {read} are damaged (first at {first})",
                              file=path)  # fmt: skip
        primary = self._primary(streams)
        built = {name: self._build(s) for name, s in streams.items()}
        main = built[primary]
        decisions: dict[str, Any] = {"primary_laser": primary, **main.decisions}
        for name, b in built.items():  # the other lasers' choices, under their names
            decisions.update({k: v for k, v in b.decisions.items() if k.startswith(name)})
        odometry, groundtruth, poses = self._poses(main, decisions)
        if lines.stream_error is not None:
            report.note(f"the compressed stream is damaged ({lines.stream_error}); "
                        "the lines before the damage were read")  # fmt: skip
        for name, count in sorted(lines.skipped.items()):
            report.note(f"skipped {count} {name} line(s): not used")
        report.records_read = read + lines.odom.count + lines.truepos.count + lines.dpslam_odometry
        kept = sum(b.t.size for b in built.values())
        report.records_kept = kept + decisions.get("odom_lines_kept", 0)
        report.records_kept += decisions.get("truepos_lines_kept", 0)
        report.records_kept += lines.dpslam_odometry - len(lines.bad)
        for reason, number in lines.bad:
            report.drop(reason, 1, _where(path, number))
        others = {name.lower(): b for name, b in built.items() if name != primary}
        meta = make_meta(
            "carmen",
            [path],
            main.laser,
            report,
            time_source=main.time_source,
            lasers={k: v.laser for k, v in others.items()},
            carmen=decisions,
        )
        return _Plan(main, others, odometry, groundtruth, poses, meta)

    def _primary(self, streams: dict[str, _LaserStream]) -> str:
        wanted = self.options.laser
        if wanted:
            for name in streams:
                if name.lower() == wanted.lower():
                    return name
            raise ToolkitError(f"no laser {wanted!r} in the log; it has {', '.join(streams)}",
                               file=self.path)  # fmt: skip
        return next(n for n in PRIMARY_ORDER if n in streams)

    # -- one laser: clock, geometry, no-return code, mounting

    def _build(self, s: _LaserStream) -> _Built:
        report, name = self.report, s.name
        decisions: dict[str, Any] = {}
        rate = self.options.rate
        why = "no timestamps in the laser lines" if s.stamp is None else broken_clock(s.stamp)
        if why is None and s.stamp is not None:
            ok = in_order(s.stamp)
            late = np.flatnonzero(~ok)
            if late.size:
                report.drop(f"{name} timestamp out of order", late.size,
                            _where(self.path, int(s.lines[late[0]])))  # fmt: skip
                s = _take(s, ok)
            t = s.stamp
            time_source = "log"
        else:
            hz = rate if rate else NOMINAL_RATE
            t = s.index / hz
            time_source = "scan_order"
            how = f"--rate {hz:g} Hz" if rate else f"{hz:g} Hz nominal, no --rate given"
            report.note(f"{name}: {why}; times are scan order, t = scan index / rate ({how})")
            decisions["clock_fallback"] = why
            decisions["rate_hz"] = hz
        assert t is not None
        # one pass over the kept ranges: how many are NaN, inf or negative, the distinct
        # others with their counts (the no-return code, the largest value); the ranges are
        # cleaned as they are written (`_Built.blocks`)
        bad, values = 0, _Values()
        for block in s.ranges.take(s.rows):
            with np.errstate(invalid="ignore"):
                ok = np.isfinite(block) & (block >= 0)
            bad += block.size - int(np.count_nonzero(ok))
            values.add(block[ok])
        if bad:
            report.note(f"{name}: {bad} range values NaN, inf or negative -> NaN")
        geometry, code, how_code = self._geometry(s, values)
        if code is not None:
            report.note(f"{name}: no-return code {code:g} m ({how_code}): "
                        f"{values.at_least(code)} values >= {code:g} m -> NaN")  # fmt: skip
            decisions[f"{name}_no_return_from"] = round(float(code), 6)
        decisions[f"{name}_range_max"] = geometry.range_max
        decisions[f"{name}_range_max_source"] = how_code
        return _Built(s, np.ascontiguousarray(t), geometry, code, time_source, decisions)

    def _geometry(
        self, s: _LaserStream, values: _Values
    ) -> tuple[LaserGeometry, float | None, str]:
        """Beam layout, mounting and range_max; the value at and above which ranges are NaN."""
        n = s.ranges.width
        if s.header is not None:
            start, fov, res, max_range = np.median(s.header, axis=0)
            if not res > 0:
                res = fov / max(n - 1, 1)
            if np.ptp(s.header, axis=0).max() > 1e-6:
                self.report.note(f"{s.name}: the beam layout varies; the median is used")
        else:
            first, step = OLD_LAYOUTS.get(n, (-90.0, 180.0 / max(n - 1, 1)))
            if n not in OLD_LAYOUTS:
                self.report.note(f"{s.name}: {n} beams is no known layout; assumed 180° from -90°")
            start, res, max_range = math.radians(first), math.radians(step), math.nan
        explicit = self.options.range_max
        param = _param_float(self.lines, RANGE_PARAM, self.report)
        given = float(max_range) if math.isfinite(max_range) and max_range > 0 else None
        range_max: float | None = None
        code: float | None = None  # ranges at or above it become NaN
        if explicit == "none":
            range_max, how = given, "detection off (-O range_max=none)"
        elif explicit is not None:
            range_max = code = explicit
            how = "-O range_max"
        elif given is not None or param is not None:
            range_max = given if given is not None else param
            how = "max_range in the laser lines" if given is not None else f"PARAM {RANGE_PARAM}"
            assert range_max is not None
            code = range_max - 5e-4  # printed to the mm: the code itself, not a return below it
        else:
            found = values.code()
            how = "detected: largest value recurring at the top"
            if found is not None:
                range_max, code = found, found * (1 - CODE_BAND)
            else:
                how += "; none found"
        if range_max is None:
            top = values.top()
            range_max = _as_printed(top) if np.isfinite(top) else 81.91
            how += ", range_max = the largest reading"
        return LaserGeometry(n, float(start), float(res), range_max, **self._mount(s)), code, how

    def _mount(self, s: _LaserStream) -> dict[str, float]:
        """Laser mounting in the robot frame: PARAM offset for x, pose difference for the rest."""
        lp, rp = s.laser_pose, s.robot_pose
        ok = np.isfinite(lp).all(axis=1) & np.isfinite(rp).all(axis=1)
        dx = dy = dyaw = 0.0
        if ok.any():
            c, sn = np.cos(rp[ok, 2]), np.sin(rp[ok, 2])
            ex, ey = lp[ok, 0] - rp[ok, 0], lp[ok, 1] - rp[ok, 1]
            dx = float(np.median(c * ex + sn * ey))
            dy = float(np.median(-sn * ex + c * ey))
            dyaw = float(np.median(se2.wrap(lp[ok, 2] - rp[ok, 2])))
        rear = s.name in REAR
        param_name = "robot_rearlaser_offset" if rear else "robot_frontlaser_offset"
        offset = _param_float(self.lines, param_name, self.report)
        if self.options.laser_x is not None:
            x, source = self.options.laser_x, "-O laser_x"
        elif offset is not None:
            x, source = offset, f"PARAM {param_name}"
            if abs(offset - dx) > 0.01 and ok.any():
                self.report.note(f"{s.name}: PARAM {param_name} {offset:g} m differs from the "
                                 f"laser-robot pose difference {dx:.3f} m; PARAM used")  # fmt: skip
        elif s.name == DPSLAM_LASER:
            # its lines repeat the Odometry pose: they say nothing of the mounting
            x, source = dx, "DP-SLAM lines carry no laser pose; its README's robot: -O laser_x=0.40"
        else:
            x, source = dx, "laser pose - robot pose in the laser lines"
        if rear and max(abs(dx), abs(dy), abs(dyaw)) < 1e-6:
            dyaw = math.pi  # the poses say nothing; a rear laser faces backwards
            self.report.note(f"{s.name}: laser and robot poses are equal; yaw pi assumed")
        mount = {k: round(v, 6) + 0.0 for k, v in (("x", x), ("y", dy), ("yaw", dyaw))}  # no -0
        self.report.note(f"{s.name}: mounting x {mount['x']:g} m ({source}), "
                         f"y {mount['y']:g} m, yaw {mount['yaw']:g} rad")  # fmt: skip
        return mount

    # -- pose streams

    def _poses(
        self, main: _Built, decisions: dict[str, Any]
    ) -> tuple[_Poses | None, _Poses | None, dict[str, _Poses]]:
        report = self.report
        scan_poses = _pose_frame(main.t, main.stream.robot_pose)
        which = self.options.poses
        clock = main.time_source == "log"
        odometry: _Poses | None = None
        if self.lines.odom.count:
            odometry = self._stamped("ODOM", self.lines.odom, clock, decisions)
        if odometry is not None:
            decisions["odometry"] = "ODOM lines at their own times"
        elif len(scan_poses):
            odometry = scan_poses
            decisions["odometry"] = f"robot pose of the {main.stream.name} lines at scan times"
        else:
            decisions["odometry"] = "none"
        truepos = None
        if self.lines.truepos.count:
            truepos = self._stamped("TRUEPOS", self.lines.truepos, clock, decisions)
        poses: dict[str, _Poses] = {}
        groundtruth: _Poses | None = truepos
        if which == "groundtruth":
            groundtruth = scan_poses
            decisions["groundtruth"] = f"robot pose of the {main.stream.name} lines (-O poses)"
            report.note(f"ground truth = the robot poses of the {main.stream.name} lines "
                        "(-O poses=groundtruth; for corrected logs, approximate)")  # fmt: skip
            carried = _laser_poses_carried(main) if self.options.equal_poses == "laser" else None
            if carried is not None:
                groundtruth = _pose_frame(main.t, carried)
                decisions["groundtruth"] = (f"laser pose of the {main.stream.name} lines, carried "
                                            "to the robot by the mounting (-O poses)")  # fmt: skip
                report.note(f"the {main.stream.name} lines' laser and robot poses are equal while "
                            "the laser is mounted off the robot's centre: the poses are taken as "
                            "the laser's (a corrector's scan poses), the ground truth as the "
                            "robot's behind them")  # fmt: skip
            if truepos is not None:
                poses["truepos"] = truepos
            if odometry is scan_poses:
                if carried is not None:
                    odometry = groundtruth
                    decisions["odometry"] += ", carried to the robot by the mounting"
                report.note("odometry is the same pose stream as the ground truth")
        elif truepos is not None:
            decisions["groundtruth"] = "TRUEPOS lines"
        if which != "groundtruth" and odometry is not scan_poses and len(scan_poses):
            poses["scan_pose"] = scan_poses
        return odometry, groundtruth, poses

    def _stamped(
        self, msg: str, lines: _PoseLines, clock: bool, decisions: dict[str, Any]
    ) -> _SpilledPoses | None:
        """ODOM or TRUEPOS poses at their own times, or None when there is no usable clock."""
        report, path = self.report, self.path
        if lines.seven == lines.count:
            report.note(f"{msg} lines not used: they have no timestamps")
            return None
        if lines.wrong_count:
            first, last = lines.wrong[0], lines.wrong[-1]
            count = lines.wrong_count
            if self.lines.last_line and last == self.lines.last_line:
                count -= 1
                report.drop("truncated last line", 1, _where(path, last))
            if count:
                report.drop(f"{msg} wrong number of fields", count, _where(path, first))
        if lines.non_numeric:
            report.drop(f"{msg} non-numeric value", len(lines.non_numeric),
                        _where(path, lines.non_numeric[0]))  # fmt: skip
        stamp = np.frombuffer(lines.stamps, dtype=np.float64)
        if not clock:
            report.note(f"{msg} lines not used: the scans have no usable clock to align them to")
            return None
        finite = np.frombuffer(bytes(lines.finite), dtype=bool)
        if not finite.all():
            report.drop(f"{msg} NaN or inf value", int((~finite).sum()),
                        _where(path, lines.number(int(np.argmin(finite)))))  # fmt: skip
            stamp = stamp[finite]
        keep = longest_in_order(stamp)
        why = broken_clock(stamp, keep)
        if why is not None:
            report.note(f"{msg} lines not used: {why}")
            return None
        late = np.flatnonzero(~keep)
        if late.size:
            first = int(np.flatnonzero(finite)[late[0]])
            report.drop(f"{msg} timestamp out of order", late.size,
                        _where(path, lines.number(first)))  # fmt: skip
        decisions[f"{msg.lower()}_lines_kept"] = int(keep.sum())
        if not keep.any():
            return None
        return _SpilledPoses(lines.values, _narrow(finite, keep))


def _narrow(mask: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """`mask` with its True entries kept where `keep` (one per True entry) is True."""
    out = mask.copy()
    out[np.flatnonzero(mask)[~keep]] = False
    return out


def _take(s: _LaserStream, keep: np.ndarray) -> _LaserStream:
    return _LaserStream(
        s.name,
        s.lines[keep],
        s.index[keep],
        s.ranges,
        _narrow(s.rows, keep),
        s.laser_pose[keep],
        s.robot_pose[keep],
        None if s.stamp is None else s.stamp[keep],
        None if s.header is None else s.header[keep],
        s.read,
    )


# ---------------------------------------------------------------- writing


def _old_layout(laser: LaserGeometry) -> bool:
    """True if the old format (no angles) describes this beam layout exactly."""
    layout = OLD_LAYOUTS.get(laser.beams)
    if layout is None:
        return False
    first, step = map(math.radians, layout)
    return abs(laser.angle_min - first) < 1e-6 and abs(laser.angle_increment - step) < 1e-6


def _rows(values: np.ndarray, fmt: str) -> list[str]:
    """Each row of a 2D array as one line of text: one %-format per row, as np.savetxt does."""
    if values.shape[0] == 0:
        return []
    line = " ".join([fmt] * values.shape[1])
    return [line % tuple(row) for row in values.tolist()]


def write_log(ds: Dataset, path: Path, host: str = "toolkit") -> None:
    """Write `ds` as one CARMEN log (see the module docstring)."""
    laser = ds.laser
    rm = f"{laser.range_max:.3f}"
    header = [
        "# message formats defined: PARAM SYNC ODOM FLASER RLASER TRUEPOS ROBOTLASER1",
        "# written by laser-toolkit; NaN ranges are written as the range_max code",
        f"PARAM robot_frontlaser_offset {laser.x:.6f} nohost 0",
        f"PARAM {RANGE_PARAM} {rm} nohost 0",
    ]
    t = ds.t
    if ds.odometry is not None and len(ds.odometry):
        robot = PoseStream.from_frame(ds.odometry).at(t)
    else:
        robot = np.zeros((t.size, 3))
    laser_pose = se2.laser_poses(robot, laser)
    code = round(laser.range_max, 3)
    # a return just below range_max must not print as the code: keep it 1 mm below
    returns = np.minimum(ds.ranges.astype(np.float64), code - 1e-3)
    ranges = np.where(np.isfinite(ds.ranges), returns, code)
    range_text = _rows(ranges, "%.3f")
    pose_text = _rows(np.column_stack([laser_pose, robot]), "%.6f")
    stamp = [f"{x:.6f} {host} {x:.6f}" for x in t]
    if _old_layout(laser):
        scans = [
            f"FLASER {laser.beams} {r} {p} {st}"
            for r, p, st in zip(range_text, pose_text, stamp, strict=True)
        ]
    else:
        head = (
            f"ROBOTLASER1 0 {laser.angle_min:.9f} {laser.fov:.9f} {laser.angle_increment:.9f} "
            f"{rm} 0.01 0 {laser.beams}"
        )
        scans = [
            f"{head} {r} 0 {p} 0 0 0 0 0 {st}"
            for r, p, st in zip(range_text, pose_text, stamp, strict=True)
        ]
    timed: list[tuple[np.ndarray, list[str]]] = [(t, scans)]
    if ds.odometry is not None and len(ds.odometry):
        o = ds.odometry
        text = _rows(o[["x", "y", "theta"]].to_numpy(), "%.6f")
        timed.append(
            (o["t"].to_numpy(), [f"ODOM {p} 0 0 0 {x:.6f} {host} {x:.6f}"
                                 for p, x in zip(text, o["t"], strict=True)])
        )  # fmt: skip
    if ds.groundtruth is not None and len(ds.groundtruth):
        g = ds.groundtruth
        gt_t = g["t"].to_numpy()
        odo = (
            PoseStream.from_frame(ds.odometry).at(gt_t)
            if ds.odometry is not None and len(ds.odometry)
            else np.zeros((gt_t.size, 3))
        )
        text = _rows(np.column_stack([g[["x", "y", "theta"]].to_numpy(), odo]), "%.6f")
        timed.append(
            (gt_t, [f"TRUEPOS {p} {x:.6f} {host} {x:.6f}" for p, x in zip(text, gt_t, strict=True)])
        )
    # one stable sort by time: pose lines before a scan with the same timestamp
    times = np.concatenate([tt for tt, _ in timed[1:]] + [t]) if len(timed) > 1 else t
    texts = [line for _, lines in timed[1:] for line in lines] + scans
    order = np.argsort(times, kind="stable")
    body = "\n".join([*header, *(texts[i] for i in order)]) + "\n"
    path.write_text(body)


# ---------------------------------------------------------------- the importer


def _sniff_lines(path: Path) -> list[list[str]]:
    head = head_bytes(path, 16384).decode("utf-8", errors="replace")
    lines = head.splitlines()
    if len(lines) > 1 and not head.endswith("\n"):
        lines = lines[:-1]  # the cut one
    tokens = [ln.split() for ln in lines]
    return [t for t in tokens if t and not t[0].startswith("#")][:5]


@dataclass(frozen=True)
class CarmenOptions(FormatOptions):
    """Reading a CARMEN log."""

    poses: Literal["odometry", "groundtruth"] = option(
        "odometry",
        "groundtruth: store the laser lines' robot poses as ground truth (the Radish "
        "'corrected' logs)",
    )
    range_max: float | Literal["none"] | None = option(
        None,
        "the no-return code in m (values at or above it -> NaN), or none",
        shown="detected per log",
    )
    laser_x: float | None = option(
        None,
        "laser mounting x in m, over PARAM robot_frontlaser_offset and the poses (DP-SLAM's "
        "README gives 0.40)",
        shown="PARAM, else the poses",
    )
    rate: float | None = option(
        None, "scans per second when the log's clock is missing or broken", shown="1", positive=True
    )
    laser: str | None = option(
        None,
        "the primary laser: flaser, robotlaser1, laser, rlaser or robotlaser2",
        shown="the first of those present",
    )
    equal_poses: Literal["robot", "laser"] = option(
        "laser",
        "with poses=groundtruth, lines whose laser and robot poses are all equal while the laser "
        "is mounted off centre (a corrector's): laser takes them as the laser's, the ground "
        "truth the robot's behind them; robot as the robot's (the reading before session 34)",
    )


@dataclass(frozen=True)
class CarmenWriteOptions(FormatOptions):
    """Writing a CARMEN log."""

    name: str = option("sim.log", "file name of the log")
    host: str = option("toolkit", "host name in every line")


@register
class Carmen(Importer[CarmenOptions, CarmenWriteOptions]):
    name = "carmen"
    summary = "CARMEN logs (FLASER/RLASER, ROBOTLASER1, ODOM, TRUEPOS, PARAM), DP-SLAM logs; gz/bz2"
    Options = CarmenOptions
    WriteOptions = CarmenWriteOptions

    def sniff(self, path: Path) -> bool:
        if not path.is_file():
            return False
        lines = _sniff_lines(path)
        if not lines:
            return False
        for tokens in lines:
            word = tokens[0]
            if word in CARMEN_TOKENS:
                continue
            if word.lower() in DPSLAM_TOKENS and len(tokens) > 1 and _NUMBER.match(tokens[1]):
                continue
            return False
        return True

    def read(self, sources: Sequence[Path], options: CarmenOptions) -> Dataset:
        if len(sources) != 1:
            raise ToolkitError(f"carmen reads one log file, got {len(sources)}")
        path = Path(sources[0])
        return _Reader(path, options).dataset()

    def import_to(
        self, sources: Sequence[Path], out: Path, options: CarmenOptions, force: bool = False
    ) -> Path:
        """The dataset `read` gives, streamed: the converted ranges and poses spill to unnamed
        files in the output's temporary folder as the text is read, and are written from there
        in Parquet row groups, so that memory holds blocks of the log, not the log."""
        if len(sources) != 1:
            raise ToolkitError(f"carmen reads one log file, got {len(sources)}")
        path = Path(sources[0])
        with atomic_dir(out, force=force) as tmp:
            _Reader(path, options, where=tmp).plan().write(tmp)
        return out

    def write(
        self, ds: Dataset, out: Path, options: CarmenWriteOptions | None = None
    ) -> list[Path]:
        """Write `ds` as the CARMEN log `out/name` (name="sim.log"), atomically; [that path]."""
        options = options or CarmenWriteOptions()
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        target = out / options.name
        with atomic_file(target) as tmp:
            write_log(ds, tmp, host=options.host)
        return [target]
