"""The dataset on disk: a directory of Parquet tables and a meta.json (docs/dataset.md).

    scans.parquet         t float64, ranges fixed_size_list<float32>[B]; NaN = no return
    scans-<name>.parquet  further lasers, geometry under meta["lasers"][name]
    odometry.parquet      t, x, y, theta float64 (wheel odometry)
    groundtruth.parquet   t, x, y, theta float64 (when the source has it)
    poses-<name>.parquet  further pose streams (e.g. ARIA's robotGlobal)
    meta.json             laser geometry, source files with sha256, import report

Every Parquet file the toolkit writes describes itself (`describe`): units and meaning per
column as Arrow field metadata, and a scans file's beam geometry as schema metadata.
Everything in memory is the same: `Dataset.ranges` is an S x B float32 array.
"""

from __future__ import annotations

import base64
import datetime as _dt
import hashlib
import json
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, overload

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit import (
    __version__,  # defined before toolkit/__init__ imports this module
    se2,
)
from toolkit.atomic import atomic_dir
from toolkit.errors import FormatError, ToolkitError

if TYPE_CHECKING:  # pose tables are DataFrames; pyarrow loads pandas when one is read, so
    import pandas as pd  # `toolkit info` and other commands that need none start without it

FORMAT_VERSION = 1
POSE_COLUMNS = ("t", "x", "y", "theta")
SCANS = "scans.parquet"
ODOMETRY = "odometry.parquet"
GROUNDTRUTH = "groundtruth.parquet"
META = "meta.json"
ROW_GROUP_SCANS = 4096  # scans per Parquet row group: the chunk a Dask worker reads and matches


@dataclass(frozen=True)
class LaserGeometry:
    """Beam layout and mounting of one laser; angles in rad, lengths in m, robot frame."""

    beams: int
    angle_min: float
    angle_increment: float
    range_max: float
    range_min: float = 0.0
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0

    @property
    def angles(self) -> np.ndarray:
        """Beam angles in the laser frame, beam 0 at angle_min."""
        return self.angle_min + self.angle_increment * np.arange(self.beams, dtype=np.float64)

    @property
    def fov(self) -> float:
        return self.angle_increment * (self.beams - 1)

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> LaserGeometry:
        known = {k: d[k] for k in cls.__dataclass_fields__ if k in d}
        return cls(**known)

    @classmethod
    def sick_180(cls, beams: int, range_max: float = 81.9, **mount: float) -> LaserGeometry:
        """A SICK LMS-2xx 180° scan from the right (-90°), as CARMEN and Rawseeds logs assume.

        181 beams = 1°, 361 = 0.5°, and the 180/360 variants that drop the last beam.
        """
        step = {181: 1.0, 180: 1.0, 361: 0.5, 360: 0.5}.get(beams)
        if step is None:
            step = 180.0 / (beams - 1)
        return cls(beams, np.deg2rad(-90.0), np.deg2rad(step), range_max, **mount)

    @classmethod
    def sick_100(cls, beams: int, range_max: float = 81.9, **mount: float) -> LaserGeometry:
        """A SICK LMS-2xx 100° scan (101, 201 or 401 beams), centred: -50° to +50°."""
        return cls(beams, np.deg2rad(-50.0), np.deg2rad(100.0 / (beams - 1)), range_max, **mount)


@dataclass
class ImportReport:
    """What an importer read and what it dropped, and why; stored in meta.json."""

    records_read: int = 0
    records_kept: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    examples: dict[str, str] = field(default_factory=dict)  # reason -> first place seen
    notes: list[str] = field(default_factory=list)

    def drop(self, reason: str, count: int = 1, where: str | None = None) -> None:
        if count <= 0:
            return
        self.dropped[reason] = self.dropped.get(reason, 0) + int(count)
        if where is not None and reason not in self.examples:
            self.examples[reason] = where

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)

    @property
    def records_dropped(self) -> int:
        return sum(self.dropped.values())

    def to_dict(self) -> dict[str, Any]:
        return {
            "records_read": self.records_read,
            "records_kept": self.records_kept,
            "records_dropped": self.records_dropped,
            "dropped": dict(self.dropped),
            "examples": dict(self.examples),
            "notes": list(self.notes),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ImportReport:
        return cls(
            int(d.get("records_read", 0)),
            int(d.get("records_kept", 0)),
            dict(d.get("dropped", {})),
            dict(d.get("examples", {})),
            list(d.get("notes", [])),
        )


@dataclass
class Scans:
    """One laser's scans: times (S,) float64 and ranges (S x B) float32."""

    t: np.ndarray
    ranges: np.ndarray
    laser: LaserGeometry

    def __post_init__(self) -> None:
        self.t = np.ascontiguousarray(self.t, dtype=np.float64)
        self.ranges = np.ascontiguousarray(self.ranges, dtype=np.float32)
        if self.ranges.ndim != 2 or self.ranges.shape[0] != self.t.shape[0]:
            raise ValueError(f"ranges {self.ranges.shape} do not match t {self.t.shape}")
        if self.ranges.shape[1] != self.laser.beams:
            raise ValueError(f"{self.ranges.shape[1]} beams, geometry says {self.laser.beams}")


class _PoseTable:
    """A Dataset's pose table (odometry, groundtruth): set as a DataFrame, a PoseStream or
    None; read as a DataFrame (t, x, y, theta float64) or None. A PoseStream is kept as it is
    and made a DataFrame on first read, so that a command that reads the poses through
    `Dataset.stream` (`toolkit map`) never loads pandas (0.24 s of an idle machine's start)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.key = f"_{name}"

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> None: ...
    @overload
    def __get__(self, obj: object, owner: type | None = None) -> pd.DataFrame | None: ...
    def __get__(self, obj: object | None, owner: type | None = None) -> pd.DataFrame | None:
        if obj is None:
            return None  # the field's default (dataclasses ask the class)
        value = obj.__dict__.get(self.key)
        if isinstance(value, PoseStream):
            value = obj.__dict__[self.key] = value.frame()
        return value

    def __set__(self, obj: object, value: pd.DataFrame | PoseStream | None) -> None:
        if value is None or isinstance(value, PoseStream):
            obj.__dict__[self.key] = value
        else:
            obj.__dict__[self.key] = _poses_frame(value)


class _PoseTables:
    """A Dataset's further pose streams by name (`poses`), as `_PoseTable` keeps one: set
    as a dict of DataFrames or PoseStreams (None: none), read as the dict of DataFrames (the
    streams made frames, in place, on first read), so that loading a dataset with such a
    stream (CARMEN's scan poses) does not load pandas."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.key = f"_{name}"

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> None: ...
    @overload
    def __get__(self, obj: object, owner: type | None = None) -> dict[str, pd.DataFrame]: ...
    def __get__(
        self, obj: object | None, owner: type | None = None
    ) -> dict[str, pd.DataFrame] | None:
        if obj is None:
            return None  # the field's default (dataclasses ask the class): no streams
        tables: dict[str, Any] = obj.__dict__[self.key]
        for name, value in tables.items():
            if isinstance(value, PoseStream):
                tables[name] = value.frame()
        return tables

    def __set__(
        self, obj: object, value: Mapping[str, pd.DataFrame | PoseStream | None] | None
    ) -> None:
        tables = {}
        for name, table in (value or {}).items():
            kept = table if isinstance(table, PoseStream) else _poses_frame(table)
            if kept is not None:
                tables[name] = kept
        obj.__dict__[self.key] = tables


@dataclass
class Dataset:
    """A log in memory: the primary laser's scans, pose streams and metadata."""

    t: np.ndarray
    ranges: np.ndarray
    laser: LaserGeometry
    # DataFrames t, x, y, theta; given (and kept, as `load` does) as a PoseStream, made a
    # DataFrame on first use (`_PoseTable`); `stream` reads them without pandas
    odometry: _PoseTable = _PoseTable()
    groundtruth: _PoseTable = _PoseTable()
    meta: dict[str, Any] = field(default_factory=dict)
    lasers: dict[str, Scans] = field(default_factory=dict)  # further lasers by name
    poses: _PoseTables = _PoseTables()  # further pose streams by name, the same way
    path: Path | None = None

    def __post_init__(self) -> None:
        primary = Scans(self.t, self.ranges, self.laser)
        self.t, self.ranges = primary.t, primary.ranges

    def stream(self, name: Literal["odometry", "groundtruth"]) -> PoseStream | None:
        """The odometry or the ground truth as a PoseStream (numpy; pandas is not loaded
        for it), None when the dataset has none."""
        value = self.__dict__.get(f"_{name}")
        if value is None or isinstance(value, PoseStream):
            return value
        return PoseStream.from_frame(value)

    @property
    def angles(self) -> np.ndarray:
        return self.laser.angles

    @property
    def n_scans(self) -> int:
        return int(self.ranges.shape[0])

    @property
    def n_beams(self) -> int:
        return int(self.ranges.shape[1])

    @property
    def report(self) -> ImportReport:
        return ImportReport.from_dict(self.meta.get("import_report", {}))

    def __len__(self) -> int:
        return self.n_scans

    def __repr__(self) -> str:
        extras = [n for n in ("odometry", "groundtruth") if getattr(self, n) is not None]
        return (
            f"Dataset({self.n_scans} scans x {self.n_beams} beams"
            + (f", {', '.join(extras)}" if extras else "")
            + (f", path={str(self.path)!r}" if self.path else "")
            + ")"
        )


@dataclass(frozen=True)
class PoseStream:
    """Timed robot poses: `t` (N,) s and `xyt` (N x 3) x, y, theta (m, rad); the odometry,
    the ground truth or a trajectory, read from and written as t, x, y, theta frames."""

    t: np.ndarray
    xyt: np.ndarray

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.t, dtype=np.float64).reshape(-1)
        xyt = np.ascontiguousarray(self.xyt, dtype=np.float64).reshape(-1, 3)
        if len(t) != len(xyt):
            raise ValueError(f"{len(t)} times but {len(xyt)} poses")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "xyt", xyt)

    def __len__(self) -> int:
        return len(self.t)

    def at(self, t: np.ndarray) -> np.ndarray:
        """Poses at times `t` (len(t) x 3) by `toolkit.se2.interpolate` (heading on the
        circle, clamped at the ends); a copy of the poses when `t` are the stream's times."""
        t = np.asarray(t, dtype=np.float64)
        if len(t) == len(self.t) and np.array_equal(t, self.t):
            return self.xyt.copy()
        if len(self.t) == 0:
            raise ToolkitError("pose stream is empty")
        return se2.interpolate(self.t, self.xyt, t)

    def _columns(self) -> pa.Table:
        x, y, theta = (np.ascontiguousarray(c, np.float64) for c in self.xyt.T)
        arrays = [_float64_array(c) for c in (self.t, x, y, theta)]
        return pa.Table.from_arrays(arrays, names=list(POSE_COLUMNS))

    def frame(self) -> pd.DataFrame:
        """DataFrame t, x, y, theta (float64)."""
        frame: pd.DataFrame = self._columns().to_pandas()  # pandas loaded here, on use
        return frame

    def table(self) -> pa.Table:
        """Arrow table t, x, y, theta (float64), the same as `pa.Table.from_pandas(self.frame(),
        preserve_index=False)`, pandas' schema metadata included (so a Parquet file of it is
        byte for byte the one the DataFrame gave, and pandas reads it back as that frame),
        without loading pandas (`toolkit map`'s trajectory.parquet)."""
        table = self._columns()
        columns = [
            {"name": c, "field_name": c, "pandas_type": "float64", "numpy_type": "float64"}
            | {"metadata": None}
            for c in POSE_COLUMNS
        ]
        pandas_meta = {
            "index_columns": [],
            "column_indexes": [],
            "columns": columns,
            "attributes": {},
            "creator": {"library": "pyarrow", "version": pa.__version__},
            "pandas_version": _pandas_version(),
        }
        return table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})

    @classmethod
    def from_frame(cls, frame: pd.DataFrame) -> PoseStream:
        """The stream of a t, x, y, theta frame (rows in their order)."""
        missing = [c for c in POSE_COLUMNS if c not in frame.columns]
        if missing:
            raise ValueError(f"pose table lacks columns {missing}")
        return cls(frame["t"].to_numpy(np.float64), frame[["x", "y", "theta"]].to_numpy(np.float64))


def _float64_array(values: np.ndarray) -> pa.Array:
    """A float64 Arrow array over the buffer of `values` (1-D float64, contiguous); not
    `pa.array`, which loads pandas (0.24 s) to check whether `values` are pandas'."""
    values = np.ascontiguousarray(values, np.float64)
    return pa.Array.from_buffers(pa.float64(), len(values), [None, pa.py_buffer(values)])


def _pandas_version() -> str:
    """The installed pandas' version, from its distribution's metadata (not by importing
    it: 0.24 s)."""
    import importlib.metadata  # noqa: PLC0415  (on use: 0.01-0.02 s)

    return importlib.metadata.version("pandas")


def write_csv(path: Path, rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> None:
    """`rows` (dicts of scalars) as CSV, byte for byte what `pandas.DataFrame(rows,
    columns=None if rows else columns).to_csv(path, index=False)` writes, without loading
    pandas (`toolkit map`'s loops.csv): the columns in the order their keys first come (just
    `columns` with no rows); a column of bools True/False, of ints as ints, of numbers (ints
    and floats, None as NaN) as numpy's shortest float64 text, as pandas; None and NaN empty;
    anything else by `str`."""
    import csv  # noqa: PLC0415  (on use)

    names = list(dict.fromkeys(k for row in rows for k in row)) if rows else list(columns)
    text = [_csv_texts([row.get(name) for row in rows]) for name in names]
    with open(path, "w", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(names)
        writer.writerows(zip(*text, strict=True))


def _csv_texts(values: list[Any]) -> list[str]:
    """One column's values as pandas writes them (`write_csv`), by the dtype pandas gives it."""
    if values and all(isinstance(v, bool | np.bool_) for v in values):
        return ["True" if v else "False" for v in values]
    number = (int, float, np.integer, np.floating)
    if all(v is None or (isinstance(v, number) and not isinstance(v, bool)) for v in values):
        if values and all(isinstance(v, int | np.integer) for v in values):
            return [str(int(v)) for v in values]
        floats = np.array([np.nan if v is None else v for v in values], np.float64)
        out: list[str] = floats.astype(str).tolist()
        return ["" if np.isnan(f) else o for f, o in zip(floats, out, strict=True)]
    return ["" if v is None or (isinstance(v, float) and v != v) else str(v) for v in values]


def pose_frame(t: np.ndarray, xyt: np.ndarray) -> pd.DataFrame:
    """DataFrame t, x, y, theta of poses `xyt` (N x 3) at times `t`."""
    return PoseStream(t, xyt).frame()


def _poses_frame(frame: pd.DataFrame | None) -> pd.DataFrame | None:
    if frame is None:
        return None
    missing = [c for c in POSE_COLUMNS if c not in frame.columns]
    if missing:
        raise ValueError(f"pose table lacks columns {missing}")
    out = frame.loc[:, list(POSE_COLUMNS)].astype(np.float64)
    return out.reset_index(drop=True)


# ---------------------------------------------------------------- self-describing Parquet

_ROBOT_AXES = "robot frame: x forward, y left"
#: the frame of each kind of pose table (schema metadata "frame")
FRAMES = {
    "odometry": "odometry frame: the robot's pose as its wheel odometry integrates it, from the "
    f"log's start ({_ROBOT_AXES}, theta counter-clockwise)",
    "groundtruth": "the ground truth's world frame, as the source defines it (see meta.json)",
    "poses": "the source's frame for this pose stream (see meta.json)",
    "trajectory": "the odometry's frame: the corrected trajectory starts at the odometry's "
    "first pose (the origin without odometry)",
    "labels": "",
    "truth": "the simulated world's frame",
}
#: per column: (unit, meaning), stored as Arrow field metadata "unit" and "description"
COLUMNS: dict[str, tuple[str, str]] = {
    "t": ("s", "time, in the dataset's time base (meta.json time_source)"),
    "ranges": (
        "m",
        "range per beam, beam i at angle_min + i * angle_increment (schema metadata); "
        "NaN = no return",
    ),
    "x": ("m", "position of the robot along the x axis of the table's frame (schema metadata)"),
    "y": ("m", "position of the robot along the y axis of the table's frame (schema metadata)"),
    "theta": (
        "rad",
        "heading of the robot (its x axis, forward), counter-clockwise from the frame's x axis",
    ),
    "label": (
        "",
        "place: the true one (truth.parquet) or the one with the highest posterior "
        "(labels.parquet; 'none' when no feature fits)",
    ),
    "section": ("", "Table 1 section of the simulated log (0..7), -1 if none"),
}


def _column_doc(name: str) -> tuple[str, str] | None:
    if name.startswith("p_"):
        return "1", f"posterior probability that the robot is at {name[2:]!r}"
    return COLUMNS.get(name)


def describe(table: pa.Table, kind: str, **schema_meta: object) -> pa.Table:
    """`table` with each known column's unit and meaning as Arrow field metadata, and `kind`,
    its frame and `schema_meta` (JSON unless a string) as schema metadata, so that
    `pyarrow.parquet.read_schema` of the file says what meta.json says. No data is copied."""
    return pa.Table.from_arrays(
        table.columns, schema=describe_schema(table.schema, kind, **schema_meta)
    )


def describe_schema(schema: pa.Schema, kind: str, **schema_meta: object) -> pa.Schema:
    """The schema `describe` gives a table of `schema`."""
    fields, units = [], {}
    for f in schema:
        doc = _column_doc(f.name)
        if doc is not None:
            units[f.name] = doc[0]
            meta = {**(f.metadata or {}), b"unit": doc[0].encode(), b"description": doc[1].encode()}
            f = f.with_metadata(meta)
        fields.append(f)
    extra: dict[str, object] = {"toolkit_table": kind, "units": units}
    if FRAMES.get(kind):
        extra["frame"] = FRAMES[kind]
    extra.update(schema_meta)
    meta = dict(schema.metadata or {})
    meta.update(
        {
            k.encode(): (v if isinstance(v, str) else json.dumps(v)).encode()
            for k, v in extra.items()
        }
    )
    return pa.schema(fields, metadata=meta)


def scans_metadata(laser: LaserGeometry, source: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Schema metadata of a scans table: the beam angles and mounting (meta.json's laser)."""
    out: dict[str, Any] = {
        "beams": str(laser.beams),
        "angle_min": repr(float(laser.angle_min)),
        "angle_increment": repr(float(laser.angle_increment)),
        "range_min": repr(float(laser.range_min)),
        "range_max": repr(float(laser.range_max)),
        "laser": laser.to_dict(),
        "frame": "laser frame: beam angles in rad counter-clockwise from the laser's x axis "
        "(forward), beam 0 at angle_min; the laser is mounted on the robot at laser x, y, z "
        f"(m), yaw (rad) ({_ROBOT_AXES})",
    }
    if source is not None:
        out["source"] = dict(source)
    return out


def write_described(
    path: Path, data: pd.DataFrame | pa.Table, kind: str, **schema_meta: object
) -> None:
    """Write a table to Parquet with its units, meaning and frame (`describe`); zstd."""
    table = data if isinstance(data, pa.Table) else pa.Table.from_pandas(data, preserve_index=False)
    pq.write_table(describe(table, kind, **schema_meta), path, compression="zstd")


# ---------------------------------------------------------------- Parquet tables


def scans_table(t: np.ndarray, ranges: np.ndarray) -> pa.Table:
    """Arrow table for scans: the float32 ranges become a fixed-size list without a copy."""
    ranges = np.ascontiguousarray(ranges, dtype=np.float32)
    beams = ranges.shape[1]
    values = pa.array(ranges.reshape(-1), type=pa.float32())
    lists = pa.FixedSizeListArray.from_arrays(values, beams)
    return pa.table({"t": pa.array(np.asarray(t, dtype=np.float64)), "ranges": lists})


def scans_schema(
    beams: int, laser: LaserGeometry | None = None, source: Mapping[str, Any] | None = None
) -> pa.Schema:
    """The scans table's schema: units per column, and with `laser` the beam angles."""
    plain = pa.schema([("t", pa.float64()), ("ranges", pa.list_(pa.float32(), beams))])
    extra = scans_metadata(laser, source) if laser is not None else {}
    return describe_schema(plain, "scans", **extra)


class ScansWriter:
    """Append scans batch by batch to a Parquet file: imports of huge logs in constant memory.

    Rows are buffered into row groups of `ROW_GROUP_SCANS` scans, whatever the batches, so that
    row group k holds scans k*N .. (k+1)*N - 1 (the chunks `toolkit.app.fleet` hands to workers)."""

    def __init__(
        self,
        path: Path,
        beams: int,
        group: int = ROW_GROUP_SCANS,
        laser: LaserGeometry | None = None,
        source: Mapping[str, Any] | None = None,
    ) -> None:
        self.path = path
        self.beams = beams
        self.group = group
        self.rows = 0
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []
        self._buffered = 0
        self._schema = scans_schema(beams, laser, source)
        self._writer = pq.ParquetWriter(path, self._schema, compression="zstd")

    def write(self, t: np.ndarray, ranges: np.ndarray) -> None:
        if len(t):
            self._pending.append((t, ranges))
            self._buffered += len(t)
            self.rows += len(t)
            if self._buffered >= self.group:
                self._flush(final=False)

    def _flush(self, final: bool) -> None:
        if not self._pending:
            return
        t = np.concatenate([p[0] for p in self._pending])
        ranges = np.concatenate([p[1] for p in self._pending])
        whole = len(t) if final else len(t) - len(t) % self.group
        if whole:
            table = scans_table(t[:whole], ranges[:whole]).cast(self._schema)
            self._writer.write_table(table, row_group_size=self.group)
        self._pending = [(t[whole:], ranges[whole:])] if whole < len(t) else []
        self._buffered = len(t) - whole

    def close(
        self, laser: LaserGeometry | None = None, source: Mapping[str, Any] | None = None
    ) -> None:
        """Finish the file; `laser` (and `source`), when only known at the end (a geometry
        decided by the whole log), become the schema metadata read_schema returns."""
        self._flush(final=True)
        if laser is not None:
            schema = scans_schema(self.beams, laser, source)
            serialized = base64.b64encode(schema.serialize().to_pybytes()).decode()
            self._writer.add_key_value_metadata({"ARROW:schema": serialized})
        self._writer.close()

    def __enter__(self) -> ScansWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_scans(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a scans table as (t, S x B float32 ranges). ParquetFile, not read_table: the
    latter goes through pyarrow.dataset, which loads pandas (0.3-0.8 s)."""
    table = pq.ParquetFile(path).read()
    return column_numpy(table.column("t")), _ranges(table, path)


def read_scan_rows(path: Path, start: int, stop: int) -> np.ndarray:
    """The ranges (float32) of scans start..stop-1 of a scans table, decoding only the row
    groups that hold them (a worker's chunk of a long log on shared storage)."""
    parquet = pq.ParquetFile(path)
    meta = parquet.metadata
    ends = np.cumsum([meta.row_group(i).num_rows for i in range(meta.num_row_groups)])
    if not 0 <= start < stop <= (ends[-1] if len(ends) else 0):
        raise ToolkitError(f"rows {start}..{stop - 1} are not in this scans table", file=path)
    first, last = np.searchsorted(ends, [start, stop - 1], side="right")
    offset = int(ends[first - 1]) if first else 0
    groups = list(range(first, last + 1))
    table = parquet.read_row_groups(groups, columns=["ranges"], use_threads=False)
    return _ranges(table, path)[start - offset : stop - offset]


_NUMPY = {pa.float64(): np.float64, pa.float32(): np.float32, pa.int64(): np.int64}


def column_numpy(column: pa.ChunkedArray | pa.Array) -> np.ndarray:
    """A float or int64 column as numpy, from its buffer (no copy for one chunk): pyarrow's
    own to_numpy loads pandas (0.3-0.8 s), which `toolkit info` would otherwise pay."""
    arr = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    dtype = _NUMPY.get(arr.type)
    if dtype is None or arr.null_count:
        return np.asarray(arr.to_numpy(zero_copy_only=False))
    if len(arr) == 0:
        return np.empty(0, dtype)
    return np.frombuffer(arr.buffers()[1], dtype, len(arr), arr.offset * np.dtype(dtype).itemsize)


def _ranges(table: pa.Table, path: Path) -> np.ndarray:
    ranges_col = table.column("ranges")
    list_type = ranges_col.type
    if not pa.types.is_fixed_size_list(list_type):
        raise FormatError("ranges is not a fixed-size list", file=path)
    beams = list_type.list_size
    lists = ranges_col.combine_chunks()
    # the child values of the rows (not .flatten(): it loads pyarrow.compute, 0.05-0.15 s)
    flat = lists.values.slice(lists.offset * beams, len(lists) * beams)
    return column_numpy(flat).reshape(len(table), beams)


def write_scans(
    path: Path,
    t: np.ndarray,
    ranges: np.ndarray,
    laser: LaserGeometry | None = None,
    source: Mapping[str, Any] | None = None,
) -> None:
    """A scans table in row groups of `ROW_GROUP_SCANS` scans, self-described (`describe`)."""
    table = scans_table(t, ranges)
    table = table.cast(scans_schema(table.column("ranges").type.list_size, laser, source))
    pq.write_table(table, path, row_group_size=ROW_GROUP_SCANS, compression="zstd")


def write_poses(path: Path, frame: pd.DataFrame) -> None:
    """A pose table (t, x, y, theta); its kind (odometry, groundtruth, poses) from its name."""
    kind = {ODOMETRY: "odometry", GROUNDTRUTH: "groundtruth"}.get(Path(path).name, "poses")
    write_described(path, frame, kind)


def read_poses(path: Path) -> pd.DataFrame | None:
    return pq.ParquetFile(path).read().to_pandas() if path.exists() else None


def read_pose_stream(path: Path) -> PoseStream | None:
    """A pose table (t, x, y, theta) as a PoseStream, read straight into numpy (`read_poses`'
    values, without pandas); None when there is no such file."""
    if not path.exists():
        return None
    table = pq.ParquetFile(path).read()
    missing = [c for c in POSE_COLUMNS if c not in table.column_names]
    if missing:
        raise ValueError(f"pose table lacks columns {missing}")
    t, x, y, theta = (column_numpy(table.column(c)).astype(np.float64) for c in POSE_COLUMNS)
    return PoseStream(t, np.column_stack([x, y, theta]))


# ---------------------------------------------------------------- provenance


def path_distance(xy: np.ndarray) -> np.ndarray:
    """Distance travelled along a path (S x 2 positions) up to each pose, from 0 (turning on
    the spot adds none; a NaN step adds none)."""
    steps = np.hypot(*np.diff(np.asarray(xy, dtype=np.float64), axis=0).T)
    return np.concatenate([[0.0], np.cumsum(np.nan_to_num(steps))])


def sha256(path: Path, chunk: int = 1 << 22) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def source_entries(paths: Iterable[Path]) -> list[dict[str, Any]]:
    return [
        {"path": str(p), "bytes": p.stat().st_size, "sha256": sha256(p)}
        for p in sorted({Path(p) for p in paths})
    ]


def make_meta(
    fmt: str,
    sources: Sequence[Path],
    laser: LaserGeometry,
    report: ImportReport,
    *,
    time_source: str = "log",
    lasers: Mapping[str, LaserGeometry] | None = None,
    **extra: object,
) -> dict[str, Any]:
    """meta.json content: geometry, provenance, import report, and format-specific decisions."""
    meta: dict[str, Any] = {
        "format_version": FORMAT_VERSION,
        "toolkit_version": __version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "source": {"format": fmt, "files": source_entries(sources)},
        "laser": laser.to_dict(),
        "lasers": {k: v.to_dict() for k, v in (lasers or {}).items()},
        "time_source": time_source,
        "import_report": report.to_dict(),
    }
    meta.update(extra)
    return meta


# ---------------------------------------------------------------- whole datasets


MAX_POSITION = 1e6  # m: beyond any robot's log (1000 km); a corrupt field, not a pose
MAX_RANGE = 1e6  # m: beyond any laser
TIME_BACKWARDS = 1e-3  # s: scan times may not go back by more (t is non-decreasing)


def plausible_poses(
    frame: pd.DataFrame | None, report: ImportReport, what: str
) -> pd.DataFrame | None:
    """`frame` without the poses no robot can have (a non-finite field, a position beyond
    `MAX_POSITION`), dropped and counted in `report` under `what`."""
    if frame is None or not len(frame):
        return frame
    values = frame[["t", "x", "y", "theta"]].to_numpy(np.float64)
    bad = ~np.isfinite(values).all(axis=1) | (np.abs(values[:, 1:3]) > MAX_POSITION).any(axis=1)
    if not bad.any():
        return frame
    first = int(np.argmax(bad))
    report.drop(
        f"{what}: implausible pose (non-finite, or beyond {MAX_POSITION:.0e} m)",
        int(bad.sum()),
        f"row {first} (t={float(values[first, 0])!r}, x={float(values[first, 1])!r}, "
        f"y={float(values[first, 2])!r})",
    )
    kept: pd.DataFrame = frame.loc[~bad].reset_index(drop=True)
    return kept


def check_scans(t: np.ndarray, ranges: np.ndarray | None, where: Path | None) -> int:
    """Refuse scan times that are not finite or go backwards (beyond `TIME_BACKWARDS`); set
    impossible ranges (infinite, negative, beyond `MAX_RANGE`) to NaN, in place. Returns how
    many ranges were set to NaN."""
    if len(t) and not np.isfinite(t).all():
        i = int(np.argmax(~np.isfinite(t)))
        raise FormatError(f"scan {i} has time {float(t[i])!r}", file=where)
    back = np.diff(t) < -TIME_BACKWARDS
    if back.any():
        i = int(np.argmax(back)) + 1
        raise FormatError(
            f"scan times go backwards at scan {i} ({float(t[i - 1])!r} -> {float(t[i])!r} s)",
            file=where,
        )
    if ranges is None or not ranges.size:
        return 0
    with np.errstate(invalid="ignore"):
        bad = ~((ranges >= 0) & (ranges <= MAX_RANGE)) & ~np.isnan(ranges)
    count = int(np.count_nonzero(bad))
    if count:
        ranges[bad] = np.nan
    return count


def write_dataset_files(ds: Dataset, directory: Path, *, scans_written: bool = False) -> None:
    """Write every table and meta.json of `ds` into an existing directory, after the
    plausibility checks (`check_scans`, `plausible_poses`) that no dataset may fail."""
    source = ds.meta.get("source")
    report = ds.report
    files = ds.meta.get("source", {}).get("files") or [{}]
    origin = Path(files[0].get("path", "dataset"))  # what errors name
    fixed = check_scans(ds.t, None if scans_written else ds.ranges, origin)
    for extra in ds.lasers.values():
        fixed += check_scans(extra.t, extra.ranges, origin)
    if fixed:
        report.note(f"{fixed} impossible range(s) (infinite, negative, > 1e6 m) set to NaN")
    ds.odometry = plausible_poses(ds.odometry, report, "odometry")
    ds.groundtruth = plausible_poses(ds.groundtruth, report, "groundtruth")
    for name in list(ds.poses):
        ds.poses[name] = plausible_poses(ds.poses[name], report, name)  # type: ignore[assignment]
    if report.records_dropped or report.notes or "import_report" in ds.meta:
        ds.meta["import_report"] = report.to_dict()
    if not scans_written:
        write_scans(directory / SCANS, ds.t, ds.ranges, ds.laser, source)
    for name, extra in ds.lasers.items():
        write_scans(directory / f"scans-{name}.parquet", extra.t, extra.ranges, extra.laser, source)
    if ds.odometry is not None:
        write_poses(directory / ODOMETRY, ds.odometry)
    if ds.groundtruth is not None:
        write_poses(directory / GROUNDTRUTH, ds.groundtruth)
    for name, frame in ds.poses.items():
        write_poses(directory / f"poses-{name}.parquet", frame)
    meta = dict(ds.meta)
    meta.setdefault("format_version", FORMAT_VERSION)
    meta["laser"] = ds.laser.to_dict()
    meta["lasers"] = {k: v.laser.to_dict() for k, v in ds.lasers.items()}
    meta["scans"] = ds.n_scans
    meta["beams"] = ds.n_beams
    (directory / META).write_text(json.dumps(meta, indent=2, allow_nan=False) + "\n")


def save(ds: Dataset, out: str | Path, force: bool = False) -> Path:
    """Write `ds` as a dataset directory, atomically."""
    out = Path(out)
    with atomic_dir(out, force=force) as tmp:
        write_dataset_files(ds, tmp)
    ds.path = out
    return out


def is_unfinished(path: Path) -> bool:
    """A folder an atomic write is still filling (or left by a killed one): `.NAME.XXXX.tmp`
    (toolkit.atomic); it is never a dataset, whatever it holds."""
    return path.name.startswith(".") and path.name.endswith(".tmp")


def is_dataset_dir(path: str | Path) -> bool:
    """Whether `path` is a dataset directory: a folder holding meta.json or scans.parquet (a
    damaged one too: loading it then says what is missing), not an unfinished write. The one
    rule that the fleet's search, `toolkit map`, the report and `load` go by."""
    path = Path(path)
    return (
        path.is_dir()
        and not is_unfinished(path)
        and ((path / META).exists() or (path / SCANS).exists())
    )


def check_dataset_dir(path: Path) -> Path:
    """`path` if it is a dataset directory with both meta.json and scans.parquet; else a
    ToolkitError that says what is missing (before any work is done)."""
    if not path.is_dir() or is_unfinished(path):
        raise ToolkitError("not a dataset directory", file=path)
    missing = [f for f in (META, SCANS) if not (path / f).is_file()]
    if missing:
        raise ToolkitError(f"not a dataset: {', '.join(missing)} missing", file=path)
    return path


@contextmanager
def reading(file: Path) -> Iterator[None]:
    """A damaged dataset file (truncated Parquet, wrong columns, a meta.json that is no
    dataset's) as a one-line error naming it, not an exception from pyarrow."""
    try:
        yield
    except ToolkitError:
        raise
    except (pa.ArrowException, OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        what = " ".join(str(e).split())[:200] or type(e).__name__
        raise FormatError(f"damaged or not a dataset's file ({what})", file=file) from None


def read_meta(path: Path) -> dict[str, Any]:
    """The meta.json of the dataset directory `path`; ToolkitError unless it is one."""
    check_dataset_dir(path)
    meta_path = path / META
    try:
        meta: dict[str, Any] = json.loads(meta_path.read_text())
    except json.JSONDecodeError as e:
        raise ToolkitError(f"invalid JSON: {e.msg}", file=meta_path, record=e.lineno) from None
    return meta


def load(path: str | Path) -> Dataset:
    """Read a dataset directory written by `toolkit import` (or `save`)."""
    path = Path(path)
    meta = read_meta(path)
    meta_path = path / META
    with reading(meta_path):
        laser = LaserGeometry.from_dict(meta["laser"])
        extra = dict(meta.get("lasers", {}))
    with reading(path / SCANS):
        t, ranges = read_scans(path / SCANS)
    lasers = {}
    for name, geometry in extra.items():
        file = path / f"scans-{name}.parquet"
        with reading(file):
            lt, lr = read_scans(file)
            lasers[name] = Scans(lt, lr, LaserGeometry.from_dict(geometry))
    poses = {}
    for p in sorted(path.glob("poses-*.parquet")):
        with reading(p):
            poses[p.stem.removeprefix("poses-")] = read_pose_stream(p)
    with reading(path / ODOMETRY):
        odometry = read_pose_stream(path / ODOMETRY)
    with reading(path / GROUNDTRUTH):
        groundtruth = read_pose_stream(path / GROUNDTRUTH)
    return Dataset(
        t=t,
        ranges=ranges,
        laser=laser,
        odometry=odometry,
        groundtruth=groundtruth,
        meta=meta,
        lasers=lasers,
        poses=poses,
        path=path,
    )
