"""ARIA laser logs (`aria`, `.2d`): what ArLaserLogger writes on Pioneer robots.

Text, one ``tag: values`` per line, ``#`` comments, unknown tags ignored (see FORMATS.md).
A scan block ends with its laser line: ``scan1:`` (x y points per beam, mm, robot frame;
``0 0`` = ignored beam -> NaN) or the older ``sick1:`` (one integer range per beam, mm;
0 = no reading -> NaN). The ``logTime:`` (or older ``time:``), ``robot:`` (encoder pose ->
odometry) and ``robotGlobal:`` (corrected pose -> ``Dataset.poses["robotGlobal"]``) lines seen
since the previous laser line belong to that scan. ``cairn:`` goal markers are skipped.

Header, by version (this module's reading; it accepts every variant in every version):

- version 2: ``sick1pose: X Y TH`` (mm, deg), ``sick1conf: FIRST LAST N``, ``time:``.
- version 3: ``scan1pose: X Y Z TH`` (or ``sick1pose`` with three or four values),
  ``locationTypes:`` naming the pose streams, ``logTime:``.
- version 4: as 3, plus ``scanId:`` and ``velocities:`` per scan.

Points become ranges per beam, vectorized over the whole log: the point minus the laser's
mounting position, projected on the beam's direction in the robot frame (beam angle from
``sick1conf`` plus the mounting yaw). Readings at or beyond ``range_max`` (``-O range_max=``,
default 81.91 m, the LMS-200's largest) become NaN. Damaged lines (wrong value count,
non-numbers, a last laser line without its line end: the write was cut) are dropped and
counted in the import report; a file that is not an ARIA log,
or has no scan, is a FormatError.
"""

from __future__ import annotations

import csv
import io
import math
import re
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
from rich.progress import TaskID

from importers import register
from importers.base import FormatOptions, Importer, TextBlocks, head_bytes, option
from toolkit.atomic import atomic_file
from toolkit.dataset import Dataset, ImportReport, LaserGeometry, PoseStream, make_meta, pose_frame
from toolkit.errors import FormatError, ToolkitError
from toolkit.progress import task

MM = 0.001
DEFAULT_RANGE_MAX = 81.91
MAX_BEAMS = 10000
_KNOWN_TAGS = ("scanId", "scan1Id", "velocities", "locationTypes", "robotRaw")
PARSE_ROWS = 4096  # laser lines converted in one call (bounded memory)
SUFFIXES = (".2d", ".2d.gz", ".2d.bz2", ".2d.xz")
LASER_TAGS = ("scan1", "sick1")
TIME_TAGS = ("logTime", "time")
_NUMBER_CHARS = re.compile(r"[0-9.eE+\- \t]*")
_TAG = re.compile(r"^\s*([A-Za-z][A-Za-z0-9_]*)\s*:(.*)$")


class _Scans:
    """Scan records as parsed, before the vectorized conversion."""

    def __init__(self) -> None:
        self.width = 0  # numbers per laser line
        self.lines: list[int] = []
        self.t: list[float] = []
        self.text: list[str] = []  # the laser lines' numbers not yet converted
        self.robot: list[tuple[float, float, float] | None] = []
        self.global_: list[tuple[float, float, float] | None] = []
        self._ok: list[np.ndarray] = []  # converted, PARSE_ROWS texts at a time
        self._values: list[np.ndarray] = []

    def add_text(self, text: str) -> None:
        """A laser line's numbers; converted in blocks, so that the text is not all kept."""
        self.text.append(text)
        if len(self.text) >= PARSE_ROWS:
            self._flush()

    def _flush(self) -> None:
        if self.text:
            ok, values = parse_rows(self.text, self.width)
            self._ok.append(ok)
            self._values.append(values)
            self.text = []

    def parsed(self) -> tuple[np.ndarray, np.ndarray]:
        """(ok per laser line, values of the ok ones), as `parse_rows` of all of them."""
        self._flush()
        if not self._ok:
            return parse_rows([], self.width)
        ok, values = np.concatenate(self._ok), np.concatenate(self._values)
        self._ok, self._values = [], []
        return ok, values


@dataclass(frozen=True)
class AriaOptions(FormatOptions):
    """Reading an ARIA log."""

    range_max: float = option(
        DEFAULT_RANGE_MAX, "readings at or beyond this (m) become NaN", positive=True
    )
    rate: float | None = option(
        None, "scans per second for a log without logTime:/time:", shown="1", positive=True
    )


@dataclass(frozen=True)
class AriaWriteOptions(FormatOptions):
    """Writing an ARIA log."""

    version: Literal[2, 3, 4] = option(4, "log version: 2 (time:) or 3/4 (logTime:)")
    points: bool = option(True, "scan1: points (true) or the older sick1: ranges (false)")
    name: str = option("log", "file name: NAME.2d")


@register
class Aria(Importer[AriaOptions, AriaWriteOptions]):
    name = "aria"
    summary = "ARIA ArLaserLogger laser log (.2d): scan1 points or sick1 ranges, robot poses"
    Options = AriaOptions
    WriteOptions = AriaWriteOptions

    def sniff(self, path: Path) -> bool:
        log = _find_log(path) if path.is_dir() else path
        if log is None or not log.is_file():
            return False
        head = head_bytes(log, 4096)
        if b"\x00" in head:
            return False
        text = head.decode("utf-8", "replace")
        first = text.lstrip().split("\n", 1)[0].strip()
        return (
            first == "LaserOdometryLog"
            or re.search(r"^#.*ArLaserLogger", text, re.M) is not None  # its header comment
            or re.search(r"^\s*(sick1conf|scan1conf)\s*:", text, re.M) is not None
        )

    def read(self, sources: Sequence[Path], options: AriaOptions) -> Dataset:
        paths = [Path(p) for p in sources]
        if len(paths) == 1 and paths[0].is_dir():
            found = _find_log(paths[0])
            if found is None:
                raise ToolkitError("expected one .2d log in the directory", file=paths[0])
            paths = [found]
        if len(paths) != 1:
            raise ToolkitError("aria takes one .2d log")
        path = paths[0]
        report = ImportReport()
        header, scans = _parse(path, report)
        return _build(path, header, scans, report, options.range_max, self.name, options.rate)

    def write(self, ds: Dataset, out: Path, options: AriaWriteOptions | None = None) -> list[Path]:
        o = options or AriaWriteOptions()
        return [write(ds, out, version=o.version, points=o.points, name=o.name)]


def _find_log(directory: Path) -> Path | None:
    logs = sorted(p for p in directory.iterdir() if p.name.lower().endswith(SUFFIXES))
    return logs[0] if len(logs) == 1 else None


def _numbers(text: str, count: int | None = None) -> list[float] | None:
    """The whitespace-separated finite numbers of `text`, or None if any is not one."""
    try:
        values = [float(v) for v in text.split()]
    except ValueError:
        return None
    if (count is not None and len(values) != count) or not all(map(math.isfinite, values)):
        return None
    return values


def _lines(path: Path, report: ImportReport) -> Iterator[tuple[int, str]]:
    """Numbered lines; a damaged compressed stream ends them (noted), what came before is kept."""
    number = 0
    size = path.stat().st_size
    reader = TextBlocks(path)  # bounded: line length and decompressed size capped
    with task(f"reading {path.name}", total=size) as (bar, job):
        for block in reader:
            # as a text file reads: \r\n and \r are newlines
            lines = block.replace("\r\n", "\n").replace("\r", "\n").split("\n")
            last = lines.pop()  # "" after the block's final newline, else the cut last line
            for line in lines:
                number += 1
                yield number, line + "\n"
            if last:
                number += 1
                yield number, last
            bar.update(TaskID(job), completed=min(reader.bytes, size))
    if reader.error is not None:
        report.note(f"compressed stream damaged after line {number} ({reader.error}): "
                    "the rest is lost")  # fmt: skip


def parse_rows(texts: list[str], width: int) -> tuple[np.ndarray, np.ndarray]:
    """Parse whitespace-separated numbers, `width` per text, all texts in one C-parser call.

    Returns (ok per text, values of the ok texts, n_ok x width). A text is not ok if it holds
    more or fewer numbers, something that is not a number, or a non-finite value.
    """
    ok = np.zeros(len(texts), bool)
    if not texts or width <= 0:
        return ok, np.zeros((0, max(width, 0)))
    # only number characters (a stray quote or carriage return would confuse the CSV parser)
    clean = [row if _NUMBER_CHARS.fullmatch(row) else "" for row in texts]
    # each row starts with its index: rows the parser skips (too many fields) are known
    text = "\n".join(f"{i} {row}" for i, row in enumerate(clean))
    with warnings.catch_warnings():  # short rows are expected here and found below
        warnings.simplefilter("ignore", pd.errors.ParserWarning)
        frame = _read_rows(text, width)
    numbers = frame.apply(pd.to_numeric, errors="coerce").to_numpy(np.float64)
    index = numbers[:, 0]
    finite = np.isfinite(numbers).all(axis=1)
    rows = np.flatnonzero(finite & (index >= 0) & (index < len(texts)) & (index % 1 == 0))
    at = index[rows].astype(np.int64)
    unique = np.unique(at, return_index=True)[1]  # a row index seen twice: keep the first
    rows, at = rows[unique], at[unique]
    ok[at] = True
    values = np.empty((len(texts), width))
    values[at] = numbers[rows, 1:]
    return ok, values[ok]


def _read_rows(text: str, width: int) -> pd.DataFrame:
    return pd.read_csv(
        io.StringIO(text),
        sep=r"\s+",
        header=None,
        names=range(width + 1),
        index_col=False,
        on_bad_lines="skip",
        quoting=csv.QUOTE_NONE,
        skip_blank_lines=False,
        low_memory=False,
    )


def _parse(path: Path, report: ImportReport) -> tuple[dict[str, tuple[str, int]], _Scans]:
    """One pass over the lines: header tags, and per scan its time, poses and raw values."""
    header: dict[str, tuple[str, int]] = {}
    scans = _Scans()
    t: float | None = None
    robot: tuple[float, float, float] | None = None
    robot_global: tuple[float, float, float] | None = None
    beams: int | None = None
    unknown: set[str] = set()
    seen_magic = False
    for number, line in _lines(path, report):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            seen_magic |= "ArLaserLogger" in stripped
            continue
        if stripped == "LaserOdometryLog":
            seen_magic = True
            continue
        match = _TAG.match(stripped)
        if match is None:
            if number == 1:
                raise FormatError("not an ARIA laser log (no 'tag: values' line)", file=path, record=1)  # fmt: skip
            report.drop("line without 'tag:'", where=f"line {number}")
            continue
        tag, rest = match.group(1), match.group(2)
        if tag in LASER_TAGS and not line.endswith("\n"):  # the log's last write, cut short
            report.records_read += 1
            report.drop("truncated last line", where=f"line {number}")
        elif tag in LASER_TAGS:
            report.records_read += 1
            if beams is None:
                beams = _beams_from_header(header, tag, rest, path, number)
            if header.setdefault("laser_tag", (tag, number))[0] != tag:
                report.drop(f"{tag}: log mixes scan1 and sick1", where=f"line {number}")
            else:
                scans.width = 2 * beams if tag == "scan1" else beams
                scans.lines.append(number)
                scans.t.append(math.nan if t is None else t)
                scans.add_text(rest)
                scans.robot.append(robot)
                scans.global_.append(robot_global)
            t = robot = robot_global = None
        elif tag in TIME_TAGS:
            value = _numbers(rest, 1)
            if value is None:
                report.drop(f"{tag}: not a number", where=f"line {number}")
            t = None if value is None else value[0]
        elif tag in ("robot", "robotGlobal"):
            pose = _numbers(rest, 3)
            if pose is None:
                report.drop(f"{tag}: not X Y TH", where=f"line {number}")
            elif tag == "robot":
                robot = (pose[0], pose[1], pose[2])
            else:
                robot_global = (pose[0], pose[1], pose[2])
        elif tag == "cairn":
            report.records_read += 1
            report.drop("goal marker (cairn:) skipped", where=f"line {number}")
        elif tag in ("sick1pose", "scan1pose", "sick1conf", "scan1conf", "version"):
            if beams is not None and tag in ("sick1conf", "scan1conf"):
                report.note(f"{tag} after the first scan ignored (line {number})")
            else:
                header[tag] = (rest.strip(), number)
                if tag in ("sick1conf", "scan1conf"):
                    header["conf"] = header[tag]
                if tag in ("sick1pose", "scan1pose"):
                    header["pose"] = header[tag]
        elif tag not in _KNOWN_TAGS and len(unknown) < 100:  # garbage: millions of words
            unknown.add(tag)
    if unknown:
        report.note(f"unknown tags ignored: {', '.join(sorted(unknown))}")
    if not seen_magic and "conf" not in header:
        raise FormatError(
            "not an ARIA laser log (no LaserOdometryLog header, no sick1conf)", file=path
        )
    return header, scans


def _beams_from_header(
    header: dict[str, tuple[str, int]], tag: str, rest: str, path: Path, number: int
) -> int:
    """The beam count: sick1conf's N, else what the first laser line holds."""
    conf = header.get("conf")
    if conf is not None:
        text, line = conf
        values = _numbers(text, 3)
        if values is None or not values[2].is_integer() or not 2 <= values[2] <= MAX_BEAMS:
            raise FormatError(f"sick1conf: expected FIRST LAST N (N 2..{MAX_BEAMS}), got {text!r}", file=path, record=line)  # fmt: skip
        if not values[1] > values[0] or values[1] - values[0] > 360:
            raise FormatError(f"sick1conf: bad angles {text!r}", file=path, record=line)
        return int(values[2])
    count = len(rest.split())
    beams = count // 2 if tag == "scan1" else count
    if not 2 <= beams <= MAX_BEAMS:
        raise FormatError(f"{tag}: {beams} beams and no sick1conf", file=path, record=number)
    return beams


def _mounting(header: dict[str, tuple[str, int]], path: Path) -> tuple[float, float, float, float]:
    """(x, y, z, yaw) in m and rad from sick1pose/scan1pose (X Y TH or X Y Z TH, mm and deg)."""
    pose = header.get("pose")
    if pose is None:
        return 0.0, 0.0, 0.0, 0.0
    text, line = pose
    values = _numbers(text)
    if values is None or len(values) not in (3, 4):
        raise FormatError(f"laser pose: expected X Y [Z] TH, got {text!r}", file=path, record=line)
    x, y, *rest = values
    z, th = (0.0, rest[0]) if len(rest) == 1 else (rest[0], rest[1])
    return x * MM, y * MM, z * MM, math.radians(th)


def _geometry(
    header: dict[str, tuple[str, int]], beams: int, range_max: float, path: Path
) -> tuple[LaserGeometry, str | None]:
    x, y, z, yaw = _mounting(header, path)
    conf = header.get("conf")
    if conf is None:
        laser = LaserGeometry.sick_180(beams, range_max, x=x, y=y, z=z, yaw=yaw)
        return laser, f"no sick1conf: {beams} beams taken as a SICK 180° scan from -90°"
    values = _numbers(conf[0], 3)
    assert values is not None  # checked in _beams_from_header
    first, last = math.radians(values[0]), math.radians(values[1])
    step = (last - first) / (beams - 1)
    return LaserGeometry(beams, first, step, range_max, x=x, y=y, z=z, yaw=yaw), None


def points_to_ranges(points: np.ndarray, laser: LaserGeometry) -> np.ndarray:
    """S x B x 2 points (m, robot frame; exactly 0 0 = ignored) -> S x B ranges along each beam."""
    ignored = (points[..., 0] == 0) & (points[..., 1] == 0)
    heading = laser.angles + laser.yaw
    dx = points[..., 0] - laser.x
    dy = points[..., 1] - laser.y
    ranges = dx * np.cos(heading) + dy * np.sin(heading)
    ranges[ignored | (ranges < 0)] = np.nan
    return ranges


def _poses(t: np.ndarray, poses: list[tuple[float, float, float] | None]) -> pd.DataFrame | None:
    rows = [i for i, p in enumerate(poses) if p is not None]
    if not rows:
        return None
    xyz = np.array([poses[i] for i in rows], np.float64)
    return pose_frame(t[rows], np.column_stack([xyz[:, :2] * MM, np.deg2rad(xyz[:, 2])]))


def _build(
    path: Path,
    header: dict[str, tuple[str, int]],
    scans: _Scans,
    report: ImportReport,
    range_max: float,
    fmt: str,
    rate: float | None = None,
) -> Dataset:
    tag = header["laser_tag"][0] if "laser_tag" in header else "scan1"
    ok, values = scans.parsed()
    bad = np.flatnonzero(~ok)
    if bad.size:
        where = f"line {scans.lines[int(bad[0])]}"
        report.drop(f"{tag}: not {scans.width} numbers", int(bad.size), where)
    if not ok.any():
        raise FormatError(
            f"no intact scan ({report.records_read} laser lines, {report.records_dropped} dropped)",
            file=path,
        )
    good = np.flatnonzero(ok).tolist()
    scans.t = [scans.t[i] for i in good]
    scans.robot = [scans.robot[i] for i in good]
    scans.global_ = [scans.global_[i] for i in good]
    beams = values.shape[1] // 2 if tag == "scan1" else values.shape[1]
    laser, note = _geometry(header, beams, range_max, path)
    if note:
        report.note(note)
    if tag == "scan1":
        ranges = points_to_ranges(values.reshape(len(values), beams, 2) * MM, laser)
    else:
        ranges = values * MM
        ranges[values <= 0] = np.nan
    with np.errstate(invalid="ignore"):
        ranges[ranges >= range_max] = np.nan
    t = np.asarray(scans.t, np.float64)
    time_source = "log (logTime:/time:, s)"
    missing = np.isnan(t)
    if missing.all():
        rate = rate or 1.0
        t = np.arange(len(t), dtype=np.float64) / rate
        time_source = f"scan order at {rate:g} Hz (the log has no logTime:/time:)"
        report.note(f"no timestamps: t = scan index / {rate:g} (--rate)")
        keep = np.ones(len(t), bool)
    else:
        keep = ~missing & (t >= np.fmax.accumulate(np.where(missing, -np.inf, t)))
        report.drop("scan without time", int(missing.sum()))
        report.drop("time goes backwards", int(np.sum(~keep & ~missing)))
    rows = np.flatnonzero(keep)
    t, ranges = t[rows], ranges[rows]
    report.records_kept = len(rows)
    odometry = _poses(t, [scans.robot[i] for i in rows])
    robot_global = _poses(t, [scans.global_[i] for i in rows])
    version = header.get("version")
    meta = make_meta(
        fmt,
        [path],
        laser,
        report,
        time_source=time_source,
        aria={
            "version": None if version is None else version[0],
            "laser_line": tag,
            "range_max_source": "option" if range_max != DEFAULT_RANGE_MAX else "default",
        },
    )
    return Dataset(
        t=t,
        ranges=ranges.astype(np.float32),
        laser=laser,
        odometry=odometry,
        meta=meta,
        poses={} if robot_global is None else {"robotGlobal": robot_global},
    )


# ---------------------------------------------------------------- writer


def _at(frame: pd.DataFrame | None, t: np.ndarray) -> np.ndarray | None:
    """A pose stream at times `t` (S x 3, m and rad), or None when there is none."""
    if frame is None or len(frame) == 0:
        return None
    return PoseStream.from_frame(frame).at(t)


def _pose_text(tag: str, poses: np.ndarray) -> np.ndarray:
    x, y = (np.char.mod("%.1f", poses[:, k] / MM) for k in (0, 1))
    th = np.char.mod("%.3f", np.rad2deg(poses[:, 2]))
    return np.char.add(np.char.add(np.char.add(f"{tag}: ", x), np.char.add(" ", y)), np.char.add(" ", th))  # fmt: skip


def write(
    ds: Dataset,
    out: Path,
    version: int = 4,
    points: bool = True,
    name: str = "log",
    **opts: object,
) -> Path:
    """Write `ds` as an ArLaserLogger log ``<out>/<name>.2d``; returns its path.

    `points`: ``scan1:`` points (integer mm, robot frame, ``0 0`` for NaN beams) or the older
    ``sick1:`` integer ranges (0 for NaN). Times as ``logTime:`` (version 3/4) or ``time:``
    (version 2) with 3 decimals, as ARIA prints them (ms). ``robot:`` from ds.odometry and
    ``robotGlobal:`` from ds.groundtruth (else ds.poses["robotGlobal"]), interpolated at the
    scan times, 0.1 mm and 0.001°.
    """
    if opts:
        raise ToolkitError(f"aria writer: unknown option(s) {', '.join(sorted(opts))}; known: version, points, name")  # fmt: skip
    if version not in (2, 3, 4):
        raise ToolkitError(f"aria writer: version must be 2, 3 or 4, not {version}")
    laser = ds.laser
    scans = ds.n_scans
    lines = ["LaserOdometryLog", "#Created by ArLaserLogger (laser-toolkit writer)"]
    lines.append(f"version: {version}")
    mx, my, mz = laser.x / MM, laser.y / MM, laser.z / MM
    yaw = math.degrees(laser.yaw)
    if version == 2:
        lines.append(f"sick1pose: {mx:.0f} {my:.0f} {yaw:.6g}")
    else:
        lines.append(f"scan1pose: {mx:.0f} {my:.0f} {mz:.0f} {yaw:.6g}")
    last = math.degrees(laser.angle_min + laser.angle_increment * (laser.beams - 1))
    lines.append(f"sick1conf: {math.degrees(laser.angle_min):.6g} {last:.6g} {laser.beams}")
    robot = _at(ds.odometry, ds.t)
    truth = ds.groundtruth if ds.groundtruth is not None else ds.poses.get("robotGlobal")
    robot_global = _at(truth, ds.t)
    if version >= 3:
        types = ["robot"] * (robot is not None) + ["robotGlobal"] * (robot_global is not None)
        lines.append("locationTypes: " + " ".join(types))

    ranges = ds.ranges.astype(np.float64)
    valid = np.isfinite(ranges) & (ranges > 0)
    if points:
        heading = laser.angles + laser.yaw
        px = np.rint((laser.x + ranges * np.cos(heading)) / MM)
        py = np.rint((laser.y + ranges * np.sin(heading)) / MM)
        # a real point that rounds to 0 0 would read as ignored: nudge it by 1 mm
        px[valid & (px == 0) & (py == 0)] = 1
        px[~valid], py[~valid] = 0, 0
        flat = np.stack([px, py], axis=-1).reshape(scans, -1).astype(np.int64)
        tag = "scan1: "
    else:
        flat = np.where(valid, np.rint(ranges / MM), 0).astype(np.int64)
        tag = "sick1: "
    laser_lines = [tag + " ".join(map(str, row)) for row in flat.tolist()]

    columns: list[np.ndarray] = []
    if version >= 4:
        columns.append(np.char.add("scanId: ", np.arange(1, scans + 1).astype(str)))
    time_tag = "time: " if version == 2 else "logTime: "
    columns.append(np.char.add(time_tag, np.char.mod("%.3f", ds.t)))
    if version >= 4:
        columns.append(np.full(scans, "velocities: 0 0 0"))
    if robot is not None:
        columns.append(_pose_text("robot", robot))
    if robot_global is not None:
        columns.append(_pose_text("robotGlobal", robot_global))
    columns.append(np.array(laser_lines, dtype=object))
    body = np.column_stack([c.astype(object) for c in columns]).reshape(-1)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    target = out / f"{name}.2d"
    with atomic_file(target) as tmp:
        tmp.write_text("\n".join([*lines, *body.tolist()]) + "\n")
    return target
