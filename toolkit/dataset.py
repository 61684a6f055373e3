"""The dataset on disk: a directory of Parquet tables and a meta.json (see DESIGN.md).

    scans.parquet         t float64, ranges fixed_size_list<float32>[B]; NaN = no return
    scans-<name>.parquet  further lasers, geometry under meta["lasers"][name]
    odometry.parquet      t, x, y, theta float64 (wheel odometry)
    groundtruth.parquet   t, x, y, theta float64 (when the source has it)
    poses-<name>.parquet  further pose streams (e.g. ARIA's robotGlobal)
    meta.json             laser geometry, source files with sha256, import report

Everything in memory is the same: `Dataset.ranges` is an S x B float32 array.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.atomic import atomic_dir
from toolkit.errors import FormatError, ToolkitError

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


@dataclass
class Dataset:
    """A log in memory: the primary laser's scans, pose streams and metadata."""

    t: np.ndarray
    ranges: np.ndarray
    laser: LaserGeometry
    odometry: pd.DataFrame | None = None
    groundtruth: pd.DataFrame | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    lasers: dict[str, Scans] = field(default_factory=dict)  # further lasers by name
    poses: dict[str, pd.DataFrame] = field(default_factory=dict)  # further pose streams
    path: Path | None = None

    def __post_init__(self) -> None:
        primary = Scans(self.t, self.ranges, self.laser)
        self.t, self.ranges = primary.t, primary.ranges
        self.odometry = _poses_frame(self.odometry)
        self.groundtruth = _poses_frame(self.groundtruth)
        self.poses = {k: f for k, v in self.poses.items() if (f := _poses_frame(v)) is not None}

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


def _poses_frame(frame: pd.DataFrame | None) -> pd.DataFrame | None:
    if frame is None:
        return None
    missing = [c for c in POSE_COLUMNS if c not in frame.columns]
    if missing:
        raise ValueError(f"pose table lacks columns {missing}")
    out = frame.loc[:, list(POSE_COLUMNS)].astype(np.float64)
    return out.reset_index(drop=True)


# ---------------------------------------------------------------- Parquet tables


def scans_table(t: np.ndarray, ranges: np.ndarray) -> pa.Table:
    """Arrow table for scans: the float32 ranges become a fixed-size list without a copy."""
    ranges = np.ascontiguousarray(ranges, dtype=np.float32)
    beams = ranges.shape[1]
    values = pa.array(ranges.reshape(-1), type=pa.float32())
    lists = pa.FixedSizeListArray.from_arrays(values, beams)
    return pa.table({"t": pa.array(np.asarray(t, dtype=np.float64)), "ranges": lists})


def scans_schema(beams: int) -> pa.Schema:
    return pa.schema([("t", pa.float64()), ("ranges", pa.list_(pa.float32(), beams))])


class ScansWriter:
    """Append scans batch by batch to a Parquet file: imports of huge logs in constant memory.

    Rows are buffered into row groups of `ROW_GROUP_SCANS` scans, whatever the batches, so that
    row group k holds scans k*N .. (k+1)*N - 1 (the chunks `toolkit.app.fleet` hands to workers)."""

    def __init__(self, path: Path, beams: int, group: int = ROW_GROUP_SCANS) -> None:
        self.path = path
        self.beams = beams
        self.group = group
        self.rows = 0
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []
        self._buffered = 0
        self._writer = pq.ParquetWriter(path, scans_schema(beams), compression="zstd")

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
            table = scans_table(t[:whole], ranges[:whole])
            self._writer.write_table(table, row_group_size=self.group)
        self._pending = [(t[whole:], ranges[whole:])] if whole < len(t) else []
        self._buffered = len(t) - whole

    def close(self) -> None:
        self._flush(final=True)
        self._writer.close()

    def __enter__(self) -> ScansWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_scans(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a scans table as (t, S x B float32 ranges)."""
    table = pq.read_table(path)
    return table.column("t").to_numpy(), _ranges(table, path)


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


def _ranges(table: pa.Table, path: Path) -> np.ndarray:
    ranges_col = table.column("ranges")
    list_type = ranges_col.type
    if not pa.types.is_fixed_size_list(list_type):
        raise FormatError("ranges is not a fixed-size list", file=path)
    beams = list_type.list_size
    flat = ranges_col.combine_chunks().flatten() if len(table) else pa.array([], pa.float32())
    return flat.to_numpy(zero_copy_only=False).reshape(len(table), beams)


def write_scans(path: Path, t: np.ndarray, ranges: np.ndarray) -> None:
    """A scans table in row groups of `ROW_GROUP_SCANS` scans."""
    pq.write_table(scans_table(t, ranges), path, row_group_size=ROW_GROUP_SCANS, compression="zstd")


def write_poses(path: Path, frame: pd.DataFrame) -> None:
    pq.write_table(pa.Table.from_pandas(frame, preserve_index=False), path, compression="zstd")


def read_poses(path: Path) -> pd.DataFrame | None:
    return pd.read_parquet(path) if path.exists() else None


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
    **extra: Any,
) -> dict[str, Any]:
    """meta.json content: geometry, provenance, import report, and format-specific decisions."""
    from toolkit import __version__

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


def write_dataset_files(ds: Dataset, directory: Path, *, scans_written: bool = False) -> None:
    """Write every table and meta.json of `ds` into an existing directory."""
    if not scans_written:
        write_scans(directory / SCANS, ds.t, ds.ranges)
    for name, extra in ds.lasers.items():
        write_scans(directory / f"scans-{name}.parquet", extra.t, extra.ranges)
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


def load(path: str | Path) -> Dataset:
    """Read a dataset directory written by `toolkit import` (or `save`)."""
    path = check_dataset_dir(Path(path))
    meta_path = path / META
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as e:
        raise ToolkitError(f"invalid JSON: {e.msg}", file=meta_path, record=e.lineno) from None
    laser = LaserGeometry.from_dict(meta["laser"])
    t, ranges = read_scans(path / SCANS)
    lasers = {}
    for name, geometry in meta.get("lasers", {}).items():
        lt, lr = read_scans(path / f"scans-{name}.parquet")
        lasers[name] = Scans(lt, lr, LaserGeometry.from_dict(geometry))
    poses = {
        p.stem.removeprefix("poses-"): pd.read_parquet(p)
        for p in sorted(path.glob("poses-*.parquet"))
    }
    return Dataset(
        t=t,
        ranges=ranges,
        laser=laser,
        odometry=read_poses(path / ODOMETRY),
        groundtruth=read_poses(path / GROUNDTRUTH),
        meta=meta,
        lasers=lasers,
        poses=poses,
        path=path,
    )
