"""The runs a report needs, made with the toolkit's own functions: trajectories by each method
(timed here) and the labels learnt from a log's training regions."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from reports.base import NotAvailable, require
from toolkit.dataset import Dataset, pose_frame, write_described

RUNS = "runs"  # the report's folder of run outputs (trajectories, metrics, labels)

if TYPE_CHECKING:
    from reports.context import Context, Run


@dataclass
class LabelRun:
    """A feature model learnt from a log's training spans and the labels it gives every scan."""

    dataset: str
    spans: list[Any]  # toolkit.features.Span
    training: dict[str, np.ndarray]  # feature -> scan indices
    model: Any  # toolkit.features.FeatureModel
    labels: Any  # toolkit.features.Labels: .classes, .prob (S x K), .label
    seconds: float
    truth: np.ndarray | None = None  # true label per scan, when known (simulated logs)
    files: list[str] = field(default_factory=list)  # model.json, labels.parquet (report-relative)

    def probability(self, feature: str) -> np.ndarray:
        return np.asarray(self.labels.prob[:, self.labels.classes.index(feature)])


def label_run(ctx: Context, name: str, ds: Dataset) -> LabelRun:
    """Learn the features of log `name` from its training regions and label every scan."""
    features = require("toolkit.features", "fit", "classify", "read_regions", "training_indices")
    truth = None
    if name == "corridor":
        sim = ctx.corridor()
        spans = features.spans_from_frame(sim.regions, ds.t)
        truth = np.asarray(sim.labels).astype(str)
    else:
        source = ctx.sources[name]
        if source.regions is None:
            raise NotAvailable(f"{name} has no training regions (regions.csv)")
        spans = features.read_regions(source.regions, ds.t)
        truth = truth_labels(source.truth or source.path, ds.t)
    training = features.training_indices(spans)
    poses = require("toolkit.poses", "odometry_poses").odometry_poses(ds)  # at the scan times
    t0 = time.perf_counter()
    model = features.fit(ds.ranges, ds.laser, training, features.Config(), spans)
    labels = features.classify(model, ds.ranges, poses)
    seconds = time.perf_counter() - t0
    # what `toolkit label` keeps: the model and the labels of every scan
    folder = Path(RUNS) / safe_name(name) / "labels"
    (ctx.out / folder).mkdir(parents=True, exist_ok=True)
    model.save(ctx.out / folder / "model.json")
    write_described(ctx.out / folder / "labels.parquet", labels.frame(ds.t), "labels")
    files = [str(folder / "model.json"), str(folder / "labels.parquet")]
    return LabelRun(name, spans, training, model, labels, seconds, truth, files)


def truth_labels(path: Path | None, t: np.ndarray) -> np.ndarray | None:
    """True labels of the scans at times `t` from a simulated log's truth.parquet (given, or
    inside or beside its folder), matched by time: a capture that lost frames keeps the rest."""
    if path is None:
        return None
    candidates = [path] if path.suffix == ".parquet" else [path / "truth.parquet"]
    for candidate in [*candidates, path.parent / "truth.parquet"]:
        if not candidate.is_file():
            continue
        frame = pd.read_parquet(candidate)
        if "label" not in frame:
            continue
        labels = frame["label"].astype(str).to_numpy()
        if "t" not in frame or len(frame) < 2:
            return labels if len(labels) == len(t) else None
        ft = frame["t"].to_numpy(np.float64)
        k = np.clip(np.searchsorted(ft, t), 1, max(len(ft) - 1, 1))
        nearest = np.where(np.abs(ft[k - 1] - t) <= np.abs(ft[k] - t), k - 1, k)
        if len(ft) and np.all(np.abs(ft[nearest] - t) <= 1e-3):
            return labels[nearest]
    return None


def map_run(ctx: Context, name: str, ds: Dataset, method: str) -> Run:
    """The trajectory of `ds` by `method`, timed, with ATE/RPE against ground truth if any."""
    from reports.context import Run

    traj = require("toolkit.poses", "build", "truth_poses")
    mapping = require("toolkit.mapping", "run_metrics", "write_tum")
    if method == "odometry" and ds.odometry is None:
        raise NotAvailable(f"{name} has no odometry")
    warm_up(ds, method)
    result = traj.build(ds, method)
    scores: dict[str, Any] = mapping.run_metrics(ds, result)  # what `toolkit map` writes
    # the run's trajectory (TUM, for evo) and metrics.json go into the report
    folder = Path(RUNS) / safe_name(name) / method
    (ctx.out / folder).mkdir(parents=True, exist_ok=True)
    mapping.write_tum(ctx.out / folder / "trajectory.tum", ds.t, result.poses)
    (ctx.out / folder / "metrics.json").write_text(json.dumps(scores, indent=2) + "\n")
    files = [str(folder / "trajectory.tum"), str(folder / "metrics.json")]
    truth_file = folder.parent / "groundtruth.tum"
    truth = None if (ctx.out / truth_file).exists() else traj.truth_poses(ds)
    if truth is not None:
        mapping.write_tum(ctx.out / truth_file, ds.t, truth)
        files.append(str(truth_file))
    return Run(name, method, result.frame, result.seconds, scores, files)


_warm: set[tuple[str, int]] = set()


WARM_UP_SCANS = 50  # Open3D's first hundred pairs run slow (thread pool, allocations)


def warm_up(ds: Dataset, method: str) -> None:
    """Match some pairs first so that no timing includes compiling kernels or Open3D's
    start-up (measured: the first full section by Open3D ICP took 4-5x the next ones)."""
    if method == "odometry" or (method, ds.n_beams) in _warm or ds.n_scans < 3:
        return
    from toolkit.poses import build

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


def with_drift(ds: Dataset, seed: int = 0) -> Dataset:
    """`ds` with odometry made by the simulator's wheel-odometry model (default parameters:
    unequal wheels, scale error, noise, slips) along its ground truth at the scan times."""
    sim = require("toolkit.sim", "OdometryModel")
    traj = require("toolkit.poses", "truth_poses")
    truth = traj.truth_poses(ds)
    if truth is None:
        raise NotAvailable("no ground truth to add drift to")
    odo = sim.OdometryModel().integrate(truth, np.random.default_rng(seed))
    frame = pose_frame(ds.t, odo)
    meta = {**ds.meta, "odometry": "simulated wheel odometry along the ground truth (drift added)"}
    return Dataset(
        t=ds.t,
        ranges=ds.ranges,
        laser=ds.laser,
        odometry=frame,
        groundtruth=ds.groundtruth,
        meta=meta,
        path=ds.path,
    )


def world_points(ds: Dataset, poses: np.ndarray, every: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Every return of every `every`-th scan at its world position and the laser's height
    (N x 3), and the index of its scan, through the map builder (toolkit.mapping)."""
    mapping = require("toolkit.mapping", "world_points")
    idx = np.arange(0, ds.n_scans, max(every, 1))
    xy, scan = mapping.world_points(ds.ranges[idx], np.asarray(poses)[idx], ds.laser)
    z = np.full((len(xy), 1), float(ds.laser.z))
    return np.hstack([np.asarray(xy), z]), idx[np.asarray(scan)]


def safe_name(name: str) -> str:
    """A log's name as part of a file name."""
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)


def poses_at(frame: pd.DataFrame, t: np.ndarray) -> np.ndarray:
    """Poses (S x 3) of a pose table at times `t` (the trajectory module's interpolation)."""
    return np.asarray(require("toolkit.poses", "poses_at").poses_at(frame, t))
