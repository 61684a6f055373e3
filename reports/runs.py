"""The runs a report needs, made with the toolkit's own functions: trajectories by each method
(timed here) and the labels learnt from a log's training regions."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from reports.base import NotAvailable, require
from toolkit.dataset import Dataset

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
    training = features.training_indices(spans)
    poses = None
    if ds.odometry is not None and len(ds.odometry) == ds.n_scans:
        poses = ds.odometry[["x", "y", "theta"]].to_numpy()
    t0 = time.perf_counter()
    model = features.fit(ds.ranges, ds.laser, training, features.Config(), spans)
    labels = features.classify(model, ds.ranges, poses)
    seconds = time.perf_counter() - t0
    return LabelRun(name, spans, training, model, labels, seconds, truth)


def map_run(ctx: Context, name: str, ds: Dataset, method: str) -> Run:
    """The trajectory of `ds` by `method`, timed, with ATE/RPE against ground truth if any."""
    raise NotAvailable("toolkit.trajectory is not in the toolkit yet")


def path_distance(xy: np.ndarray) -> np.ndarray:
    """Distance travelled along a path (S x 2) up to each pose, from 0."""
    steps = np.hypot(*np.diff(np.asarray(xy, dtype=np.float64), axis=0).T)
    return np.concatenate([[0.0], np.cumsum(np.nan_to_num(steps))])


def poses_at(frame: pd.DataFrame, t: np.ndarray) -> np.ndarray:
    """Poses (S x 3) of a pose table at times `t` (linear in x, y and unwrapped theta)."""
    ft = frame["t"].to_numpy()
    x = np.interp(t, ft, frame["x"].to_numpy())
    y = np.interp(t, ft, frame["y"].to_numpy())
    th = np.interp(t, ft, np.unwrap(frame["theta"].to_numpy()))
    return np.column_stack([x, y, np.arctan2(np.sin(th), np.cos(th))])
