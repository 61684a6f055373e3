"""`table`: plain numeric tables, one scan per row, in CSV or whitespace-separated text.

Layouts (`-O columns=`, comma separated, in file order):

    t, x, y, theta          time and absolute pose (odometry=absolute, the default)
    ticks_left, ticks_right cumulative wheel encoder ticks (odometry=ticks)
    ranges                  the beams: every column not named otherwise; `ranges*N` = N columns
    _  /  _*N               one / N ignored columns

Default `t,x,y,theta,ranges`. Two files (as MRPT exports `*_LASER.txt` and `*_ODO.txt`): the
ranges file (default `columns=ranges`) and the odometry file (`odo_columns`, default `x,y,theta`
for 3 columns, `t,x,y,theta` for 4), whose rows are increments (dx, dy, dtheta in the frame of
the previous pose; `odometry=increments`, the default for two files).

Units: `time_unit` s|ms|us|ns, `range_unit` m|cm|mm, `angle_unit` rad|deg (theta and the angle
options). Beam layout: `angle_increment`, or `fov` (then beams spread evenly over it), centred
on the robot's x axis unless `angle_min` is given; with neither, a SICK 180° scan from -90°
(181 beams = 1°, 361 = 0.5°). Readings equal to a `no_return` value (default 0), negative,
below `range_min` or at/above `range_max` become NaN. Rows that do not parse are dropped and
counted. `-O preset=mines` reads the BreezySLAM / Paris Mines logs (see PRESETS).

Auto-detection claims a text file whose first lines are all numeric with one constant column
count of at least 8, except files named like Rawseeds streams and Rawseeds' SICK signature
(184 comma-separated columns, the second 181): those and other ambiguous CSVs need `table`
named explicitly. A file the writer produced starts with `# table: key=value ...`, the options
it was written with; explicit -O options win over them.
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pacsv

from importers import register
from importers.base import (
    FormatOptions,
    Importer,
    TextBlocks,
    head_bytes,
    looks_like_tum,
    option,
)
from toolkit import se2
from toolkit.atomic import atomic_file
from toolkit.dataset import Dataset, ImportReport, LaserGeometry, PoseStream, make_meta, pose_frame
from toolkit.errors import FormatError, ToolkitError
from toolkit.progress import task

PRESETS: dict[str, dict[str, str]] = {
    # BreezySLAM examples/exp*.dat (Paris Mines rover): 707 tokens per line; Hokuyo URG-04LX
    # 240°, ranges in mm with 0 = no return and < 20 mm error codes; wheel radius 77 mm,
    # half axle 165 mm, 2000 ticks per revolution; laser 145 mm ahead of the axle centre.
    "mines": {
        "columns": "t,_,ticks_left,ticks_right,_*20,ranges*682,_",
        "sep": "whitespace",
        "time_unit": "us",
        "range_unit": "mm",
        "no_return": "0",
        "range_min": "20",
        "range_max": "5600",
        "angle_unit": "deg",
        "fov": "240",
        "odometry": "ticks",
        "wheel_radius": "0.077",
        "half_axle": "0.165",
        "ticks_per_rev": "2000",
        "laser_x": "0.145",
    },
}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
RANGE_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}
SEPARATORS = {"comma": ",", "whitespace": " ", "tab": "\t", "semicolon": ";", ",": ",", ";": ";"}
NAMES = ("t", "x", "y", "theta", "ticks_left", "ticks_right", "ranges")
RAWSEEDS_NAME = re.compile(r"(SICK_|HOKUYO_|ODOMETRY|GROUNDTRUTH|GT-extended|\.relations)", re.I)
_NUMBER = re.compile(rb"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(nan|inf)$", re.I)
# bytes no numeric table holds (controls, non-ASCII) become "?": their rows fail to parse
_GARBLE = bytes(b if b in (9, 10) or 32 <= b < 127 else ord("?") for b in range(256))
_HEADER = re.compile(r"^\s*#\s*table:(.*)$")


# ---------------------------------------------------------------- column layout


@dataclass(frozen=True)
class Layout:
    """Where each named column is: index of t/x/y/theta/ticks, and the ranges slice."""

    index: dict[str, int]
    ranges: slice | None
    width: int


def parse_layout(spec: str, ncols: int, where: Path) -> Layout:
    tokens = [t.strip() for t in spec.split(",") if t.strip()]
    fixed = 0
    open_ranges = False
    for tok in tokens:
        name, _, count = tok.partition("*")
        if name not in (*NAMES, "_"):
            raise ToolkitError(f"-O columns: unknown column {name!r}; known: {', '.join(NAMES)}, _")
        if count and not count.isdigit():
            raise ToolkitError(f"-O columns: {tok!r} needs a count like ranges*181 or _*4")
        if name == "ranges" and not count:
            open_ranges = True
        else:
            fixed += int(count) if count else 1
    if sum(t.partition("*")[0] == "ranges" for t in tokens) > 1:
        raise ToolkitError("-O columns: name `ranges` once")
    rest = ncols - fixed
    if (open_ranges and rest < 1) or (not open_ranges and rest != 0):
        raise FormatError(
            f"-O columns={spec} describes {fixed}{'+' if open_ranges else ''} columns, "
            f"the file has {ncols}",
            file=where,
        )
    index: dict[str, int] = {}
    ranges = None
    pos = 0
    for tok in tokens:
        name, _, count = tok.partition("*")
        width = int(count) if count else (rest if name == "ranges" else 1)
        if name == "ranges":
            ranges = slice(pos, pos + width)
        elif name != "_":
            if name in index:
                raise ToolkitError(f"-O columns: {name!r} named twice")
            index[name] = pos
        pos += width
    return Layout(index, ranges, ncols)


# ---------------------------------------------------------------- reading numbers


@dataclass
class Numbers:
    values: np.ndarray  # rows x columns, float64
    dropped: int  # rows that did not parse
    first_bad: str | None
    header_options: dict[str, str]
    header_skipped: bool


def _header_options(text: str) -> dict[str, str]:
    for line in text.splitlines()[:5]:
        if m := _HEADER.match(line):
            return dict(kv.split("=", 1) for kv in m.group(1).split() if "=" in kv and kv[0] != "=")
    return {}


def _is_number(token: bytes) -> bool:
    return bool(_NUMBER.match(token))


TABLE_BLOCK = 8 << 20  # bytes of whole lines parsed at a time (bounded memory)


def read_numbers(path: Path, sep_option: str | None) -> Numbers:
    """All rows of a numeric text table, with pyarrow's CSV reader (no Python loop per row),
    block by block of whole lines (`TextBlocks`: bounded memory, capped lines)."""
    reader = TextBlocks(path, TABLE_BLOCK, text=False)
    blocks = _with_bar(reader, path)
    try:
        first = next(blocks)
    except StopIteration:
        raise FormatError("no data rows", file=path) from None
    header = _header_options(first[:4096].decode("utf-8", "replace"))
    data = _clean(first)
    lines = [ln for ln in data[:65536].split(b"\n")[:50] if ln.strip()]
    if not lines:
        raise FormatError("no data rows", file=path)
    sep_name = sep_option or header.get("sep")
    if sep_name is None:
        sep = "," if b"," in lines[0] else " "
    elif sep_name in SEPARATORS:
        sep = SEPARATORS[sep_name]
    else:
        raise ToolkitError(f"-O sep={sep_name!r}: one of comma, whitespace, tab, semicolon")
    if sep == " ":
        lines = [re.sub(rb"[ \t]+", b" ", ln).strip() for ln in lines]
    split = [ln.split(sep.encode()) for ln in lines]
    skip = 0
    if not all(_is_number(tok.strip()) for tok in split[0] if tok.strip()):
        skip = 1  # a header line of names
        split = split[1:]
    if not split:
        raise FormatError("no data rows", file=path)
    counts = pd.Series([len(s) for s in split]).mode()
    ncols = int(counts.iloc[0])
    header_skipped = skip == 1
    parts: list[np.ndarray] = []
    bad_total, garbage_total, first_bad = 0, 0, None
    rows_before = 0
    block: bytes | None = data
    while block is not None:
        data = block
        if sep == " ":
            data = re.sub(rb"(?m)^ | $", b"", re.sub(rb"[ \t]+", b" ", data))
        values, garbage, bad = _parse_block(path, data, sep, ncols, skip)
        if first_bad is None and bad:
            first_bad = f"line {bad[0] + rows_before}" if bad[0] >= 0 else "a row"
        elif first_bad is None and garbage.any():
            first_bad = f"data row {int(np.flatnonzero(garbage)[0]) + 1 + rows_before}"
        rows_before += len(values) + len(bad) + skip
        bad_total += len(bad)
        garbage_total += int(garbage.sum())
        parts.append(values[~garbage])
        skip = 0
        nxt = next(blocks, None)
        block = None if nxt is None else _clean(nxt)
    values = np.concatenate(parts) if len(parts) > 1 else parts[0]
    return Numbers(values, bad_total + garbage_total, first_bad, header, header_skipped)


def _with_bar(reader: TextBlocks, path: Path) -> Iterator[bytes]:
    """The reader's blocks, with a bar of the bytes read (on a terminal); it closes when the
    blocks run out."""
    size = path.stat().st_size
    with task(f"reading {path.name}", total=size) as (bar, job):
        for block in reader:
            yield block
            bar.update(job, completed=min(size, reader.bytes))


def _clean(data: bytes) -> bytes:
    """Newlines unified, non-text bytes made '?', comment lines removed (line by line)."""
    data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n").translate(_GARBLE)
    return re.sub(rb"(?m)^[ \t]*#[^\n]*\n?", b"", data)


def _parse_block(
    path: Path, data: bytes, sep: str, ncols: int, skip: int
) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """(values, garbage rows, numbers of rows with the wrong field count) of one block."""
    bad: list[int] = []

    def invalid(row: pacsv.InvalidRow) -> str:
        bad.append(int(row.number) if row.number is not None else -1)
        return "skip"

    def parse(kind: pa.DataType) -> pa.Table:
        bad.clear()
        names = [f"c{i}" for i in range(ncols)]
        return pacsv.read_csv(
            io.BytesIO(data),
            read_options=pacsv.ReadOptions(column_names=names, skip_rows=skip),
            parse_options=pacsv.ParseOptions(delimiter=sep, invalid_row_handler=invalid),
            convert_options=pacsv.ConvertOptions(
                column_types=dict.fromkeys(names, kind), strings_can_be_null=True
            ),
        )

    try:
        try:  # the clean case: every token a number, straight to float64
            table = parse(pa.float64())
            values = np.column_stack(
                [c.to_numpy(zero_copy_only=False) for c in table.columns]
            ).astype(np.float64, copy=False)
            garbage = np.zeros(len(values), dtype=bool)
        except pa.ArrowInvalid as e:  # some token is not a number: find the rows, drop them
            if "Empty CSV" in str(e):
                return np.zeros((0, ncols)), np.zeros(0, dtype=bool), bad
            values, garbage = _to_float(parse(pa.string()))
    except (pa.ArrowInvalid, UnicodeDecodeError) as e:
        if "Empty CSV" in str(e):
            return np.zeros((0, ncols)), np.zeros(0, dtype=bool), bad
        what = " ".join(str(e).split())[:160]
        raise FormatError(f"not a numeric table: {what}", file=path) from None
    return values.reshape(len(values), ncols), garbage, bad


def _to_float(table: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    """Columns of strings to one float64 matrix; rows with a non-numeric token flagged."""
    rows = table.num_rows
    out = np.empty((rows, table.num_columns), dtype=np.float64)
    garbage = np.zeros(rows, dtype=bool)
    for j, column in enumerate(table.columns):
        text = column.to_pandas()
        values = pd.to_numeric(text, errors="coerce").to_numpy(np.float64, na_value=np.nan)
        nan = np.isnan(values)
        if nan.any():
            spelled = text[nan].str.strip().str.lower().isin(["nan", "-nan", "+nan", ""])
            missing = text[nan].isna().to_numpy() | spelled.to_numpy()
            garbage[np.flatnonzero(nan)[~missing]] = True
        out[:, j] = values
    return out, garbage


# ---------------------------------------------------------------- the importer


Sep = Literal["comma", "whitespace", "tab", "semicolon"]


@dataclass(frozen=True)
class TableOptions(FormatOptions):
    """Reading a table. Every option left out (None) comes from the file's own `# table:`
    line, else the preset, else the default shown."""

    columns: str | None = option(
        None, "column layout, e.g. t,_,ranges*361,_*2", shown="t,x,y,theta,ranges"
    )
    odo_columns: str | None = option(
        None, "two files: layout of the odometry file", shown="x,y,theta or t,x,y,theta"
    )
    odometry: Literal["absolute", "increments", "ticks", "none"] | None = option(
        None, "what the pose columns hold", shown="absolute (one file), increments (two)"
    )
    sep: Sep | None = option(None, "column separator", shown="comma if the first row has one")
    odo_sep: Sep | None = option(None, "two files: the odometry file's separator", shown="as sep")
    time_unit: Literal["s", "ms", "us", "ns"] | None = option(None, "unit of t", shown="s")
    range_unit: Literal["m", "cm", "mm"] | None = option(None, "unit of the ranges", shown="m")
    angle_unit: Literal["rad", "deg"] | None = option(
        None, "unit of theta and the angle options", shown="rad"
    )
    fov: float | None = option(None, "field of view; beams spread evenly over it")
    angle_min: float | None = option(None, "angle of beam 0", shown="-fov/2; SICK 180°: -90°")
    angle_increment: float | None = option(
        None, "angle between beams", shown="fov/(beams-1), or SICK 180°"
    )
    no_return: str | None = option(None, "reading(s) meaning no return, comma separated", shown="0")
    range_min: float | None = option(None, "readings below it are NaN (range unit)", shown="0")
    range_max: float | None = option(
        None, "readings at or above it are NaN (range unit)", shown="no limit"
    )
    wheel_radius: float | None = option(None, "odometry=ticks: wheel radius, m")
    half_axle: float | None = option(None, "odometry=ticks: half the wheel distance, m")
    ticks_per_rev: float | None = option(None, "odometry=ticks: encoder ticks per revolution")
    laser_x: float | None = option(None, "laser mounting x, m", shown="0")
    laser_y: float | None = option(None, "laser mounting y, m", shown="0")
    laser_z: float | None = option(None, "laser mounting z, m", shown="0")
    laser_yaw: float | None = option(None, "laser mounting yaw (angle unit)", shown="0")
    preset: Literal["mines"] | None = option(
        None, "mines: the BreezySLAM / Paris Mines logs (exp1.dat, exp2.dat)"
    )
    rate: float | None = option(None, "scans per second, for a table without t", positive=True)


@dataclass(frozen=True)
class TableWriteOptions(FormatOptions):
    """Writing a table."""

    sep: Sep = option("comma", "column separator (comma: NAME.csv, else NAME.txt)")
    name: str = option("log", "file name without suffix")


class _Options:
    """The options in force: explicit ones, over the file's own `# table:` line, over a preset."""

    def __init__(self, options: TableOptions, header: dict[str, str], where: Path) -> None:
        preset_name = options.preset or header.get("preset")
        preset = PRESETS.get(preset_name or "", {})
        try:
            base = TableOptions.parse({**preset, **header})
        except ToolkitError as e:
            raise ToolkitError(f"# table: line: {e.what}", file=where) from None
        given = {f.name: v for f in fields(options) if (v := getattr(options, f.name)) is not None}
        self.values = replace(base, **given)
        self.rate = self.values.rate

    def get(self, key: str, default: str | None = None) -> str | None:
        value = getattr(self.values, key)
        return default if value is None else str(value)

    def number(self, key: str, default: float | None = None) -> float | None:
        value = getattr(self.values, key)
        return default if value is None else float(value)

    def unit(self, key: str, table: dict[str, float], default: str) -> float:
        return table[getattr(self.values, key) or default]


@register
class TableImporter(Importer[TableOptions, TableWriteOptions]):
    name = "table"
    summary = (
        "numeric tables, one scan per row (t x y theta r1..rn; CSV or text; MRPT *_LASER/*_ODO)"
    )
    Options = TableOptions
    WriteOptions = TableWriteOptions

    def sniff(self, path: Path) -> bool:
        if not path.is_file() or RAWSEEDS_NAME.search(path.name):
            return False
        head = head_bytes(path, 65536)
        if not head or b"\0" in head or looks_like_tum(head):
            return False
        lines = [ln.strip() for ln in head.split(b"\n")[:-1] if ln.strip()]
        lines = [ln for ln in lines if not ln.startswith(b"#")][:20]
        if not lines:
            return False
        sep = b"," if b"," in lines[0] else None
        counts = set()
        for ln in lines:
            tokens = ln.split(sep)
            if not all(_is_number(t.strip()) for t in tokens):
                return False
            counts.add(len(tokens))
        if len(counts) != 1:
            return False
        ncols = counts.pop()
        mrpt = re.search(r"_(LASER|ODO)\.txt$", path.name, re.I) is not None
        rawseeds_sick = sep == b"," and ncols == 184 and lines[0].split(b",")[1].strip() == b"181"
        return (ncols >= 8 or mrpt) and not rawseeds_sick

    def read(self, sources: Sequence[Path], options: TableOptions) -> Dataset:
        paths = [Path(p) for p in sources]
        if len(paths) > 2:
            raise ToolkitError("table: give one file, or a ranges file and an odometry file")
        laser_path, odo_path = _split_sources(paths)
        scans = read_numbers(laser_path, options.sep)
        opts = _Options(options, scans.header_options, laser_path)
        report = ImportReport()
        if scans.header_skipped:
            report.note(f"{laser_path.name}: first line is a header of names; skipped")
        rows = len(scans.values) + scans.dropped
        report.records_read = rows
        report.drop(
            "row that does not parse", scans.dropped, where=f"{laser_path}: {scans.first_bad}"
        )
        if not len(scans.values):
            raise FormatError("no row parses as numbers", file=laser_path)
        default_cols = "ranges" if odo_path is not None else "t,x,y,theta,ranges"
        if opts.get("columns") is None and scans.values.shape[1] == 707:
            raise ToolkitError(
                "707 columns, like a BreezySLAM / Paris Mines log: add -O preset=mines "
                "(or -O columns=... to read it as a plain table)",
                file=laser_path,
            )
        layout = parse_layout(
            opts.get("columns", default_cols) or default_cols, scans.values.shape[1], laser_path
        )
        if layout.ranges is None:
            raise ToolkitError("-O columns: no `ranges` column")
        values = scans.values
        t = _times(values, layout, opts, laser_path, report)
        good = np.isfinite(t)
        report.drop("row without a finite time", int((~good).sum()), where=str(laser_path))
        values, t = values[good], t[good]
        if not len(t):
            raise FormatError("no row with a finite time", file=laser_path)
        order = np.argsort(t, kind="stable")
        if (np.diff(t) < 0).any():
            report.note("rows are not in time order; sorted by time")
            values, t = values[order], t[order]
        ranges, laser, n_invalid = _ranges(values[:, layout.ranges], opts, report)
        mode = opts.get("odometry") or ("increments" if odo_path else "absolute")
        if odo_path is not None:
            odometry = _odometry_file(odo_path, opts, mode, t, report)
        else:
            odometry = _poses(values, layout, opts, mode, t, laser_path)
        report.records_kept = len(t)
        meta = make_meta(
            "table",
            paths,
            laser,
            report,
            time_source="t column" if "t" in layout.index else "rate",
            table={
                "columns": opts.get("columns", default_cols),
                "odometry": mode if odometry is not None else "none",
                "preset": opts.get("preset"),
                "invalid_readings": n_invalid,
                "units": {
                    k: opts.get(k, d)
                    for k, d in (("time_unit", "s"), ("range_unit", "m"), ("angle_unit", "rad"))
                },
            },
        )
        return Dataset(t, ranges, laser, odometry=odometry, meta=meta)

    def write(self, ds: Dataset, out: Path, options: TableWriteOptions | None = None) -> list[Path]:
        """Write `out/log.csv` (sep ",") or `out/log.txt` (other separators): one scan per row,
        t, x, y, theta (odometry interpolated at the scan times, when there is odometry), ranges
        in m with 0 for no return, after a `# table:` line carrying the geometry.
        Ground truth is not written (a table has one pose per scan)."""
        o = options or TableWriteOptions()
        sep, name = SEPARATORS[o.sep], o.name
        path = Path(out) / f"{name}{'.csv' if sep == ',' else '.txt'}"
        laser = ds.laser
        columns: dict[str, np.ndarray] = {"t": ds.t}
        if ds.odometry is not None and len(ds.odometry):
            columns.update(_interpolate_pose(ds.odometry, ds.t))
        layout = ",".join([*columns, "ranges"])
        ranges = np.where(np.isnan(ds.ranges), np.float32(0), ds.ranges)
        for j in range(ds.n_beams):
            columns[f"r{j}"] = ranges[:, j]
        sep_name = o.sep
        header = (
            f"# table: columns={layout} sep={sep_name} range_unit=m angle_unit=rad no_return=0 "
            f"angle_min={laser.angle_min!r} angle_increment={laser.angle_increment!r} "
            f"range_min={laser.range_min!r} range_max={laser.range_max!r} laser_x={laser.x!r} "
            f"laser_y={laser.y!r} laser_z={laser.z!r} laser_yaw={laser.yaw!r}\n"
        )
        table = pa.table(columns)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(path) as tmp, open(tmp, "wb") as f:
            f.write(header.encode())
            pacsv.write_csv(
                table,
                f,
                pacsv.WriteOptions(include_header=False, delimiter=sep, quoting_style="none"),
            )
        return [path]


def _split_sources(paths: list[Path]) -> tuple[Path, Path | None]:
    if len(paths) == 1:
        return paths[0], None
    odo = [p for p in paths if re.search(r"_ODO\b|odo", p.stem, re.I)]
    if len(odo) == 1:
        other = paths[0] if odo[0] == paths[1] else paths[1]
        return other, odo[0]
    return paths[0], paths[1]


def _times(
    values: np.ndarray, layout: Layout, opts: _Options, where: Path, report: ImportReport
) -> np.ndarray:
    scale = opts.unit("time_unit", TIME_UNITS, "s")
    if "t" in layout.index:
        return values[:, layout.index["t"]] * scale
    rate = opts.rate
    if not rate or rate <= 0:
        raise ToolkitError("the table has no t column: give the scan rate with --rate", file=where)
    report.note(f"no time column; times from the stated rate {rate} Hz")
    return np.arange(len(values), dtype=np.float64) / rate


def _ranges(
    raw: np.ndarray, opts: _Options, report: ImportReport
) -> tuple[np.ndarray, LaserGeometry, int]:
    unit = opts.unit("range_unit", RANGE_UNITS, "m")
    angle = opts.unit("angle_unit", ANGLE_UNITS, "rad")
    beams = raw.shape[1]
    invalid = ~np.isfinite(raw) | (raw < 0)
    for token in (opts.get("no_return", "0") or "").split(","):
        if token.strip():
            invalid |= raw == float(token)
    rmin = opts.number("range_min", 0.0) or 0.0
    rmax = opts.number("range_max")
    invalid |= raw < rmin
    if rmax is not None:
        invalid |= raw >= rmax
    with np.errstate(over="ignore"):
        ranges = (raw * unit).astype(np.float32)
    invalid |= ~np.isfinite(ranges)  # beyond float32
    ranges[invalid] = np.nan
    n_invalid = int(invalid.sum())
    if n_invalid:
        report.note(f"{n_invalid} readings are no-return values or out of range: NaN")
    inc = opts.number("angle_increment")
    fov = opts.number("fov")
    amin = opts.number("angle_min")
    if inc is None and fov is None:
        base = LaserGeometry.sick_180(beams)
        inc_rad = base.angle_increment
        amin_rad = base.angle_min if amin is None else amin * angle
        report.note(f"{beams} beams and no angle options: taken as a SICK 180° scan")
    else:
        inc_rad = inc * angle if inc is not None else (fov or 0.0) * angle / max(beams - 1, 1)
        amin_rad = amin * angle if amin is not None else -inc_rad * (beams - 1) / 2
    finite = ranges[np.isfinite(ranges)]
    range_max = rmax * unit if rmax is not None else float(finite.max()) if finite.size else 0.0
    if rmax is None:
        report.note("no range_max given: the largest reading is taken as the range limit")
    mount = {k: (opts.number(f"laser_{k}", 0.0) or 0.0) for k in ("x", "y", "z")}
    yaw = (opts.number("laser_yaw", 0.0) or 0.0) * angle
    laser = LaserGeometry(beams, amin_rad, inc_rad, range_max, rmin * unit, yaw=yaw, **mount)
    return ranges, laser, n_invalid


def _poses(
    values: np.ndarray, layout: Layout, opts: _Options, mode: str, t: np.ndarray, where: Path
) -> pd.DataFrame | None:
    idx = layout.index
    if mode == "none":
        return None
    if mode == "ticks":
        if not {"ticks_left", "ticks_right"} <= set(idx):
            raise ToolkitError("odometry=ticks needs ticks_left and ticks_right in -O columns")
        return _from_ticks(values[:, idx["ticks_left"]], values[:, idx["ticks_right"]], t, opts)
    if not {"x", "y", "theta"} <= set(idx):
        return None
    angle = opts.unit("angle_unit", ANGLE_UNITS, "rad")
    x, y, th = values[:, idx["x"]], values[:, idx["y"]], values[:, idx["theta"]] * angle
    if mode == "increments":
        return _integrate(t, x, y, th)
    if mode != "absolute":
        raise ToolkitError(f"-O odometry={mode!r}: absolute, increments, ticks or none")
    return _frame(t, x, y, th)


def _frame(t: np.ndarray, x: np.ndarray, y: np.ndarray, theta: np.ndarray) -> pd.DataFrame:
    frame = pose_frame(t, np.column_stack([x, y, se2.wrap(theta)]))
    return frame[np.isfinite(frame.to_numpy()).all(axis=1)].reset_index(drop=True)


def _integrate(t: np.ndarray, dx: np.ndarray, dy: np.ndarray, dth: np.ndarray) -> pd.DataFrame:
    """Compose increments given in the frame of the previous pose (vectorized)."""
    dx, dy, dth = (np.nan_to_num(v) for v in (dx, dy, dth))
    theta = np.cumsum(dth)
    before = np.concatenate([[0.0], theta[:-1]])
    x = np.cumsum(np.cos(before) * dx - np.sin(before) * dy)
    y = np.cumsum(np.sin(before) * dx + np.cos(before) * dy)
    return _frame(t, x, y, theta)


def _from_ticks(left: np.ndarray, right: np.ndarray, t: np.ndarray, opts: _Options) -> pd.DataFrame:
    """Differential-drive dead reckoning from cumulative encoder ticks (midpoint heading)."""
    radius = opts.number("wheel_radius")
    half = opts.number("half_axle")
    per_rev = opts.number("ticks_per_rev")
    if not radius or not half or not per_rev:
        raise ToolkitError("odometry=ticks needs -O wheel_radius, half_axle and ticks_per_rev")
    metres = 2 * math.pi * radius / per_rev
    dl = np.diff(left, prepend=left[0]) * metres
    dr = np.diff(right, prepend=right[0]) * metres
    dl, dr = np.nan_to_num(dl), np.nan_to_num(dr)
    ds = (dl + dr) / 2
    dth = (dr - dl) / (2 * half)
    theta = np.cumsum(dth)
    mid = theta - dth / 2
    return _frame(t, np.cumsum(ds * np.cos(mid)), np.cumsum(ds * np.sin(mid)), theta)


def _odometry_file(
    path: Path, opts: _Options, mode: str, scan_t: np.ndarray, report: ImportReport
) -> pd.DataFrame | None:
    odo = read_numbers(path, opts.get("odo_sep"))
    report.drop("odometry row that does not parse", odo.dropped, where=f"{path}: {odo.first_bad}")
    if not len(odo.values):
        raise FormatError("no odometry row parses as numbers", file=path)
    ncols = odo.values.shape[1]
    spec = opts.get("odo_columns") or {3: "x,y,theta", 4: "t,x,y,theta"}.get(ncols)
    if spec is None:
        raise ToolkitError(f"{ncols} odometry columns: say which with -O odo_columns=", file=path)
    layout = parse_layout(spec, ncols, path)
    if "t" in layout.index:
        t = odo.values[:, layout.index["t"]] * opts.unit("time_unit", TIME_UNITS, "s")
    elif len(odo.values) == len(scan_t):
        t = scan_t
        report.note(f"{path.name}: no time column; one odometry row per scan")
    else:
        raise ToolkitError(
            f"{len(odo.values)} odometry rows for {len(scan_t)} scans and no time column",
            file=path,
        )
    return _poses(odo.values, layout, opts, mode, t, path)


def _interpolate_pose(odometry: pd.DataFrame, t: np.ndarray) -> dict[str, np.ndarray]:
    x, y, theta = PoseStream.from_frame(odometry).at(t).T
    return {"x": x, "y": y, "theta": theta}
