"""A dataset's summary: what `toolkit info` prints."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from toolkit.dataset import Dataset


def path_length(poses: pd.DataFrame | None) -> float | None:
    """Length of the path through a pose stream, in metres."""
    if poses is None or len(poses) < 2:
        return None if poses is None else 0.0
    steps = np.hypot(np.diff(poses["x"].to_numpy()), np.diff(poses["y"].to_numpy()))
    return float(np.nansum(steps))


def summary(ds: Dataset) -> dict[str, Any]:
    """Counts, geometry, timing, pose streams and the import report, as plain values."""
    duration = float(ds.t[-1] - ds.t[0]) if ds.n_scans > 1 else 0.0
    dt = np.diff(ds.t)
    rate = float(1.0 / np.median(dt)) if dt.size and np.median(dt) > 0 else None
    finite = np.isfinite(ds.ranges)
    report = ds.meta.get("import_report", {})
    return {
        "path": str(ds.path) if ds.path else None,
        "format": ds.meta.get("source", {}).get("format"),
        "scans": ds.n_scans,
        "beams": ds.n_beams,
        "fov_deg": round(float(np.rad2deg(ds.laser.fov)), 3),
        "angle_min_deg": round(float(np.rad2deg(ds.laser.angle_min)), 3),
        "angle_increment_deg": round(float(np.rad2deg(ds.laser.angle_increment)), 4),
        "range_max": ds.laser.range_max,
        "returns_fraction": round(float(finite.mean()), 4) if finite.size else 0.0,
        "t_start": float(ds.t[0]) if ds.n_scans else None,
        "duration_s": round(duration, 3),
        "rate_hz": None if rate is None else round(rate, 3),
        "time_source": ds.meta.get("time_source", "log"),
        "odometry": None if ds.odometry is None else len(ds.odometry),
        "groundtruth": None if ds.groundtruth is None else len(ds.groundtruth),
        "odometry_path_m": _round(path_length(ds.odometry)),
        "groundtruth_path_m": _round(path_length(ds.groundtruth)),
        "lasers": {k: v.ranges.shape[0] for k, v in ds.lasers.items()},
        "poses": {k: len(v) for k, v in ds.poses.items()},
        "records_read": report.get("records_read"),
        "records_dropped": report.get("records_dropped", 0),
        "dropped": report.get("dropped", {}),
        "notes": report.get("notes", []),
    }


def _round(x: float | None) -> float | None:
    return None if x is None else round(x, 3)
