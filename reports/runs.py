"""The runs a report needs, made by the toolkit's own run functions (`toolkit.mapping.map_run`,
`toolkit.features.run.label_run`, the ones `toolkit map` and `toolkit label` call) into the
report's runs/ folder, and the helpers the generators share to draw them.

This module knows nothing of the report's context: the context (reports.context) calls it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from reports.base import NotAvailable
from toolkit.dataset import Dataset
from toolkit.errors import ToolkitError
from toolkit.features.run import LabelRun, label_run
from toolkit.mapping import map_run
from toolkit.poses import build
from toolkit.raster import world_points as _world_points

RUNS = "runs"  # the report's folder of run outputs (trajectories, metrics, labels)
#: What a report's run folder holds: what evo needs side by side (trajectory.tum and
#: groundtruth.tum: `evo_ape tum groundtruth.tum trajectory.tum -a` works inside it), the
#: trajectory as Parquet, config.json and metrics.json; no cloud.ply nor map.png (the
#: report draws its own maps).
RUN_OUTPUTS = (
    "config.json",
    "trajectory.parquet",
    "trajectory.tum",
    "groundtruth.tum",
    "metrics.json",
)


@dataclass
class Run:
    """A trajectory of one log by one method, timed in this run, with its accuracy."""

    dataset: str
    method: str
    trajectory: pd.DataFrame
    seconds: float
    metrics: dict[str, Any] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)  # relative to the report


@dataclass
class Labelled:
    """A log labelled by `toolkit.features.run.label_run`, with its files in the report."""

    dataset: str
    run: LabelRun
    files: list[str] = field(default_factory=list)  # relative to the report


def map_log(out: Path, name: str, ds: Dataset, method: str) -> Run:
    """Map log `name` by `method` into OUT/runs/NAME/METHOD/ (after a warm-up, so that the
    time excludes compiling kernels), with ATE/RPE against ground truth if any."""
    if method == "odometry" and ds.odometry is None:
        raise NotAvailable(f"{name} has no odometry")
    warm_up(ds, method)
    folder = Path(RUNS) / safe_name(name) / method
    (out / folder).parent.mkdir(parents=True, exist_ok=True)
    run = map_run(ds, out / folder, method, outputs=RUN_OUTPUTS, force=True)
    files = [str(folder / f) for f in RUN_OUTPUTS if (out / folder / f).is_file()]
    return Run(name, method, run.result.frame, run.result.seconds, run.metrics, files)


def label_log(
    out: Path,
    name: str,
    ds: Dataset,
    regions: Path | pd.DataFrame,
    truth: Path | pd.DataFrame | None = None,
) -> Labelled:
    """Learn the features of log `name` from its training `regions` and label every scan along
    its odometry (what a robot has as it goes), into OUT/runs/NAME/labels/ (the model, the
    labels and labels-metrics.json; the report draws the figures)."""
    folder = Path(RUNS) / safe_name(name) / "labels"
    (out / folder).mkdir(parents=True, exist_ok=True)
    try:
        run = label_run(
            ds,
            out / folder,
            regions,
            trajectory=ds.odometry,
            force=True,
            truth=truth,
        )
    except ToolkitError as e:  # its regions or truth do not fit the log: say so, go on
        raise NotAvailable(f"labelling {name}: {e.line()}") from None
    files = sorted(str(folder / p.name) for p in (out / folder).iterdir())
    return Labelled(name, run, files)


_warm: set[tuple[str, int]] = set()


WARM_UP_SCANS = 50  # Open3D's first hundred pairs run slow (thread pool, allocations)


def warm_up(ds: Dataset, method: str) -> None:
    """Match some pairs first so that no timing includes compiling kernels or Open3D's
    start-up (measured: the first full section by Open3D ICP took 4-5x the next ones)."""
    if method == "odometry" or (method, ds.n_beams) in _warm or ds.n_scans < 3:
        return
    build(slice_scans(ds, np.arange(min(WARM_UP_SCANS, ds.n_scans))), method)
    _warm.add((method, ds.n_beams))


def slice_scans(ds: Dataset, index: np.ndarray) -> Dataset:
    """The scans `index` (consecutive) of `ds`, with odometry and ground truth over their time."""
    index = np.asarray(index)
    t = ds.t[index]

    def cut(frame: pd.DataFrame | None) -> pd.DataFrame | None:
        if frame is None:
            return None
        ft = frame["t"].to_numpy()
        lo = max(int(np.searchsorted(ft, t[0], side="right")) - 1, 0)
        hi = int(np.searchsorted(ft, t[-1], side="left")) + 1
        return frame.iloc[lo:hi].reset_index(drop=True)

    return Dataset(
        t=t,
        ranges=ds.ranges[index],
        laser=ds.laser,
        odometry=cut(ds.odometry),
        groundtruth=cut(ds.groundtruth),
        meta=ds.meta,
    )


def world_points(ds: Dataset, poses: np.ndarray, every: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Every return of every `every`-th scan at its world position and the laser's height
    (N x 3), and the index of its scan, through the map builder (toolkit.mapping)."""
    idx = np.arange(0, ds.n_scans, max(every, 1))
    xy, scan = _world_points(ds.ranges[idx], np.asarray(poses)[idx], ds.laser)
    z = np.full((len(xy), 1), float(ds.laser.z))
    return np.hstack([np.asarray(xy), z]), idx[np.asarray(scan)]


def safe_name(name: str) -> str:
    """A log's name as part of a file name."""
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)
