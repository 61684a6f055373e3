"""A dataset's summary: what `toolkit info` prints.

`summary_of(path)` reads only what the summary needs (the scans, the x and y columns of the
pose tables, the other tables' row counts) with pyarrow and numpy, without pandas, so that
`toolkit info` answers in a fraction of a second; `summary(ds)` gives the same for a Dataset
in memory.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow.parquet as pq

from toolkit.dataset import (
    GROUNDTRUTH,
    META,
    ODOMETRY,
    SCANS,
    LaserGeometry,
    column_numpy,
    read_meta,
    read_scans,
    reading,
)

if TYPE_CHECKING:
    import pandas as pd

    from toolkit.dataset import Dataset


def path_length(poses: pd.DataFrame | None) -> float | None:
    """Length of the path through a pose stream, in metres."""
    if poses is None:
        return None
    return _xy_length(poses["x"].to_numpy(), poses["y"].to_numpy())


def _xy_length(x: np.ndarray, y: np.ndarray) -> float:
    if len(x) < 2:
        return 0.0
    return float(np.nansum(np.hypot(np.diff(x), np.diff(y))))


def summary(ds: Dataset) -> dict[str, Any]:
    """Counts, geometry, timing, pose streams and the import report, as plain values."""
    streams = {
        "odometry": _xy(ds.odometry),
        "groundtruth": _xy(ds.groundtruth),
    }
    return _summary(
        ds.path,
        ds.meta,
        ds.laser,
        ds.t,
        ds.ranges,
        streams,
        {k: v.ranges.shape[0] for k, v in ds.lasers.items()},
        {k: len(v) for k, v in ds.poses.items()},
    )


def summary_of(path: str | Path) -> dict[str, Any]:
    """`summary` of the dataset directory `path`, reading only the columns it needs."""
    path = Path(path)
    meta = read_meta(path)
    with reading(path / SCANS):
        t, ranges = read_scans(path / SCANS)
    streams = {}
    for name, file in (("odometry", ODOMETRY), ("groundtruth", GROUNDTRUTH)):
        with reading(path / file):
            table = pq.ParquetFile(path / file).read(["x", "y"]) if (path / file).exists() else None
        streams[name] = (
            None
            if table is None
            else (column_numpy(table.column("x")), column_numpy(table.column("y")))
        )
    lasers = {}
    for name in meta.get("lasers", {}):
        with reading(path / f"scans-{name}.parquet"):
            lasers[name] = pq.ParquetFile(path / f"scans-{name}.parquet").metadata.num_rows
    poses = {}
    for p in sorted(path.glob("poses-*.parquet")):
        with reading(p):
            poses[p.stem.removeprefix("poses-")] = pq.ParquetFile(p).metadata.num_rows
    with reading(path / META):
        laser = LaserGeometry.from_dict(meta["laser"])
    return _summary(path, meta, laser, t, ranges, streams, lasers, poses)


def _xy(poses: pd.DataFrame | None) -> tuple[np.ndarray, np.ndarray] | None:
    return None if poses is None else (poses["x"].to_numpy(), poses["y"].to_numpy())


def _summary(
    path: Path | None,
    meta: dict[str, Any],
    laser: LaserGeometry,
    t: np.ndarray,
    ranges: np.ndarray,
    streams: dict[str, tuple[np.ndarray, np.ndarray] | None],
    lasers: dict[str, int],
    poses: dict[str, int],
) -> dict[str, Any]:
    n = int(ranges.shape[0])
    duration = float(t[-1] - t[0]) if n > 1 else 0.0
    step = _median(np.diff(t))
    rate = float(1.0 / step) if step is not None and step > 0 else None
    finite = np.isfinite(ranges)
    report = meta.get("import_report", {})
    odo, gt = streams["odometry"], streams["groundtruth"]
    return {
        "path": str(path) if path else None,
        "format": meta.get("source", {}).get("format"),
        "scans": n,
        "beams": int(ranges.shape[1]),
        "fov_deg": round(float(np.rad2deg(laser.fov)), 3),
        "angle_min_deg": round(float(np.rad2deg(laser.angle_min)), 3),
        "angle_increment_deg": round(float(np.rad2deg(laser.angle_increment)), 4),
        # 6 significant digits: a limit converted from mm (5600 x 0.001) or stored as float32
        # (a ROS bag's 5.6) is 5.6, not 5.6000000000000005 or 5.599999904632568
        "range_max": float(f"{laser.range_max:.6g}"),
        "returns_fraction": round(float(finite.mean()), 4) if finite.size else 0.0,
        "t_start": float(t[0]) if n else None,
        "duration_s": round(duration, 3),
        "rate_hz": None if rate is None else round(rate, 3),
        "time_source": meta.get("time_source", "log"),
        "odometry": None if odo is None else len(odo[0]),
        "groundtruth": None if gt is None else len(gt[0]),
        "odometry_path_m": None if odo is None else round(_xy_length(*odo), 3),
        "groundtruth_path_m": None if gt is None else round(_xy_length(*gt), 3),
        "lasers": lasers,
        "poses": poses,
        "records_read": report.get("records_read"),
        "records_dropped": report.get("records_dropped", 0),
        "dropped": report.get("dropped", {}),
        "notes": report.get("notes", []),
    }


def _median(x: np.ndarray) -> float | None:
    """The median by partition (np.median loads numpy.ma, 0.05 s of `toolkit info`)."""
    n = len(x)
    if n == 0:
        return None
    half = np.partition(x, [(n - 1) // 2, n // 2])
    return float((half[(n - 1) // 2] + half[n // 2]) / 2)
