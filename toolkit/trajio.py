"""Trajectories in and out: one reader for every option that takes a trajectory.

`read_trajectory` sniffs the file's content, not its name:

    Parquet   t, x, y, theta columns (a run's trajectory.parquet, a dataset's pose tables)
    TUM       lines `t x y z qx qy qz qw` (a run's trajectory.tum, evo, ORB-SLAM, KISS-ICP);
              theta is the quaternion's yaw, z and the other angles are dropped
    CSV       a header naming t, x, y, theta (comma separated)

and returns a DataFrame t, x, y, theta (float64, s, m, rad CCW).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from toolkit.errors import ToolkitError

POSE_COLUMNS = ["t", "x", "y", "theta"]
PARQUET_MAGIC = b"PAR1"


def trajectory_format(path: Path) -> str:
    """'parquet', 'csv' or 'tum', from the first bytes of `path`."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as e:
        raise ToolkitError(f"cannot read trajectory: {e.strerror}", file=path) from None
    if head.startswith(PARQUET_MAGIC):
        return "parquet"
    lines = [ln.strip() for ln in head.decode("utf-8", "replace").splitlines()]
    first = next((ln for ln in lines if ln and not ln.startswith("#")), "")
    names = {c.strip().lower() for c in first.split(",")}
    return "csv" if set(POSE_COLUMNS) <= names else "tum"


def read_trajectory(path: str | Path) -> pd.DataFrame:
    """Poses t, x, y, theta from a Parquet, TUM or CSV trajectory (see the module's doc)."""
    path = Path(path)
    fmt = trajectory_format(path)
    if fmt == "tum":
        return read_tum(path)
    try:
        frame = pd.read_parquet(path) if fmt == "parquet" else pd.read_csv(path, comment="#")
    except (OSError, ValueError) as e:
        raise ToolkitError(f"cannot read {fmt} trajectory: {e}", file=path) from None
    frame.columns = [str(c).strip() for c in frame.columns]
    missing = [c for c in POSE_COLUMNS if c not in frame.columns]
    if missing:
        raise ToolkitError(f"trajectory lacks columns {missing}", file=path)
    try:
        return frame[POSE_COLUMNS].astype(np.float64).reset_index(drop=True)
    except ValueError as e:
        raise ToolkitError(f"trajectory has a non-numeric value: {e}", file=path) from None


def read_tum(path: Path) -> pd.DataFrame:
    """A TUM trajectory (`t x y z qx qy qz qw` per line, `#` comments) as t, x, y, theta."""
    try:
        rows = np.loadtxt(path, comments="#", ndmin=2, dtype=np.float64)
    except ValueError as e:  # numpy names the line
        raise ToolkitError(f"not a TUM trajectory (t x y z qx qy qz qw): {e}", file=path) from None
    if rows.shape[0] == 0:
        raise ToolkitError("empty trajectory", file=path)
    if rows.shape[1] != 8:
        raise ToolkitError(
            f"not a TUM trajectory: {rows.shape[1]} columns per line, expected 8 "
            "(t x y z qx qy qz qw)",
            file=path,
        )
    t, x, y, _, qx, qy, qz, qw = rows.T
    theta = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return pd.DataFrame({"t": t, "x": x, "y": y, "theta": theta})
