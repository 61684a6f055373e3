"""`toolkit label`: learn (or load) a model, classify every scan, write the run's files.

RUN/ (created if needed; it may already hold `toolkit map`'s outputs):
    model.json           per feature, per beam: mean, variance, return probability; spans
    labels.parquet       t, p_<feature>... p_none, label
    membership.png       probability per feature along the map, and found / not found
    labels-cloud.ply     3D cloud, returns at the laser height, coloured by label
    labels-metrics.json  configuration, pose source, counts, timing (and scores vs truth)

Everything is computed first, then RUN is written atomically as a whole (toolkit.atomic).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from toolkit.atomic import atomic_dir, atomic_file
from toolkit.dataset import Dataset, PoseStream, load, write_described
from toolkit.errors import ToolkitError
from toolkit.features.classify import Labels, classify
from toolkit.features.fitting import fit
from toolkit.features.metrics import (
    balanced_accuracy,
    expected_calibration_error,
    per_class_recall,
)
from toolkit.features.model import Config, FeatureModel
from toolkit.features.regions import (
    Span,
    read_regions,
    spans_from_frame,
    training_components,
    training_indices,
)
from toolkit.progress import counted
from toolkit.trajio import read_trajectory

OUTPUTS = ("model.json", "labels.parquet", "membership.png", "labels-cloud.ply")

# draws RUN's figures into the run folder being written: (folder, dataset, name, labels,
# poses, pose source, training scans, metrics to add to), as `figures.write_figures`
FigureWriter = Callable[
    [Path, Dataset, str, Labels, np.ndarray, str, dict[str, np.ndarray], dict[str, Any]], None
]


def scan_poses(
    ds: Dataset, trajectory: Path | pd.DataFrame | None = None
) -> tuple[np.ndarray | None, str]:
    """Poses (S x 3) at the scan times: the given trajectory (a file t, x, y, theta or such a
    table), else ground truth, else odometry."""
    frame: pd.DataFrame | None
    if isinstance(trajectory, pd.DataFrame):
        frame, source = trajectory, "the trajectory given"
    elif trajectory is not None:
        frame = read_trajectory(trajectory)  # Parquet, TUM or CSV
        source = f"trajectory {trajectory}"
        _check_covers(frame, ds.t, trajectory)
    elif ds.groundtruth is not None and len(ds.groundtruth):
        frame, source = ds.groundtruth, "groundtruth"
    elif ds.odometry is not None and len(ds.odometry):
        frame, source = ds.odometry, "odometry"
    else:
        return None, "none (no poses: fixed switching per scan, no map figure)"
    return PoseStream.from_frame(frame).at(ds.t), source


COVER_TOLERANCE = 1.0  # s: how far the scans may run past a given trajectory's ends


def _check_covers(frame: pd.DataFrame, scan_t: np.ndarray, path: Path) -> None:
    """A given trajectory must have finite poses and span the scans (within
    `COVER_TOLERANCE`): interpolation would otherwise hold its last pose for the rest."""
    values = frame[["t", "x", "y", "theta"]].to_numpy(np.float64)
    if not len(values):
        raise ToolkitError("trajectory has no poses", file=path)
    bad = ~np.isfinite(values).all(axis=1)
    if bad.any():
        raise ToolkitError(
            f"trajectory has {int(bad.sum())} non-finite pose(s)",
            file=path,
            record=f"row {int(np.argmax(bad))}",
        )
    t = values[:, 0]
    lo, hi = t.min(), t.max()
    outside = (scan_t < lo - COVER_TOLERANCE) | (scan_t > hi + COVER_TOLERANCE)
    if len(scan_t) and outside.any():
        raise ToolkitError(
            f"trajectory covers {lo:.3f}..{hi:.3f} s but the scans run {scan_t[0]:.3f}.."
            f"{scan_t[-1]:.3f} s ({int(outside.sum())} of {len(scan_t)} scans outside); "
            "is it this dataset's?",
            file=path,
        )


TRUTH_TOLERANCE = 1e-3  # s: a scan takes the true label of the truth row this close in time


def truth_labels(ds: Dataset, truth: Path | pd.DataFrame | None = None) -> np.ndarray | None:
    """True label per scan, matched by time (within TRUTH_TOLERANCE): from `truth` (t, label;
    a file or a table), where every scan must find its row; else from the simulator's
    truth.parquet inside the dataset folder or beside it, when one is there and covers the
    scans (a capture that lost frames keeps the labels of those it has). None otherwise."""
    if truth is not None:
        labels = _match_truth(truth, ds.t)
        if labels is None:
            where = truth if isinstance(truth, Path) else None
            raise ToolkitError(
                f"truth has no row within {TRUTH_TOLERANCE * 1e3:g} ms of every one of the "
                f"dataset's {ds.n_scans} scans",
                file=where,
            )
        return labels
    if ds.path is None:
        return None
    for candidate in (ds.path / "truth.parquet", ds.path.parent / "truth.parquet"):
        if candidate.is_file():
            try:
                labels = _match_truth(candidate, ds.t)
            except ToolkitError:
                continue  # not a truth table for these scans
            if labels is not None:
                return labels
    return None


def _match_truth(truth: Path | pd.DataFrame, t: np.ndarray) -> np.ndarray | None:
    """The label of the truth row nearest in time to each scan, or None if a scan has none."""
    if isinstance(truth, pd.DataFrame):
        frame = truth
    else:
        try:
            frame = pd.read_parquet(truth)
        except (OSError, ValueError) as e:
            raise ToolkitError(f"cannot read truth: {e}", file=truth) from None
    if "label" not in frame or "t" not in frame:
        raise ToolkitError(
            "truth needs columns t and label", file=truth if isinstance(truth, Path) else None
        )
    ft = frame["t"].to_numpy(np.float64)
    if len(ft) == 0:
        return None
    order = np.argsort(ft, kind="stable")
    ft, labels = ft[order], frame["label"].astype(str).to_numpy()[order]
    after = np.clip(np.searchsorted(ft, t), 0, len(ft) - 1)
    before = np.maximum(after - 1, 0)
    nearest = np.where(np.abs(ft[before] - t) <= np.abs(ft[after] - t), before, after)
    if not np.all(np.abs(ft[nearest] - t) <= TRUTH_TOLERANCE):
        return None
    return np.asarray(labels[nearest])


@dataclass
class LabelRun:
    """What `label_run` computed: the model, the labels of every scan, the training scans per
    feature, the true labels when known, labels-metrics.json's content and the time taken."""

    model: FeatureModel
    labels: Labels
    spans: list[Span]
    training: dict[str, np.ndarray]  # feature -> scan indices
    truth: np.ndarray | None
    metrics: dict[str, Any]
    seconds: float

    def probability(self, feature: str) -> np.ndarray:
        """The probability of `feature` at every scan."""
        return np.asarray(self.labels.prob[:, self.labels.classes.index(feature)])


def label_run(
    dataset: Dataset | Path,
    out: Path,
    regions: Path | pd.DataFrame | None = None,
    model_path: Path | None = None,
    trajectory: Path | pd.DataFrame | None = None,
    config: Config | None = None,
    force: bool = False,
    truth: Path | pd.DataFrame | None = None,
    figures: FigureWriter | None = None,
) -> LabelRun:
    """`toolkit label`: learn from `regions` (a CSV feature,start,end or such a table) or apply
    `model_path`, classify every scan along `trajectory` (see `scan_poses`), score against
    `truth` (see `truth_labels`) and write RUN (with membership.png and labels-cloud.ply
    drawn by `figures`, e.g. `toolkit.features.figures.write_figures`, if given: the label
    command passes it, so that matplotlib and Open3D load only there). The CLI and the report both label through here."""
    if regions is None and model_path is None:
        raise ToolkitError("give --regions REGIONS.csv to learn, or --model model.json to apply")
    existing = [name for name in OUTPUTS if (out / name).exists()]
    if existing and not force:
        raise ToolkitError(f"already holds {existing[0]}; pass --force to replace", file=out)
    ds = dataset if isinstance(dataset, Dataset) else load(dataset)
    started = time.perf_counter()
    if isinstance(regions, pd.DataFrame):
        spans = spans_from_frame(regions, ds.t)
    else:
        spans = read_regions(regions, ds.t) if regions is not None else []
    training = training_indices(spans) if spans else {}
    if model_path is not None:
        model = FeatureModel.load(model_path)
        model.check_laser(ds.laser, ds.path or "the dataset")
        if config is not None:
            model = replace(model, config=replace(model.config, smoothing=config.smoothing))
    # the bars: every scan scored; the fitting (when learning) and the outputs as steps
    learn = model_path is None
    steps = ("fitting, outputs", 2) if learn else ("outputs", 1)
    with counted("label", ds.n_scans, "scans", *steps) as (scored, step):
        poses, pose_source = scan_poses(ds, trajectory)
        if learn:
            components = training_components(spans)
            model = fit(ds.ranges, ds.laser, components, config or Config(), spans, poses)
            step()
        labels = classify(model, ds.ranges, poses, progress=scored)
        seconds = time.perf_counter() - started
        metrics = _metrics(ds, model, labels, pose_source, seconds, model_path)
        true_labels = truth_labels(ds, truth)
        if true_labels is not None:
            metrics["truth"] = _scores(true_labels, labels, training)
        name = ds.path.name if ds.path else str(dataset)
        _write_run(out, ds, name, model, labels, poses, pose_source, training, metrics, figures)
        step()
    return LabelRun(model, labels, spans, training, true_labels, metrics, seconds)


def _write_run(
    out: Path,
    ds: Dataset,
    name: str,
    model: FeatureModel,
    labels: Labels,
    poses: np.ndarray | None,
    pose_source: str,
    training: dict[str, np.ndarray],
    metrics: dict[str, Any],
    figures: FigureWriter | None,
) -> None:
    """RUN as a whole: a copy of it (hard links) gets the new files, then replaces it; an
    interrupted label leaves RUN as it was."""
    with atomic_dir(out, update=True) as tmp:
        for name in (*OUTPUTS, "labels-metrics.json"):
            (tmp / name).unlink(missing_ok=True)  # never write through a link to the old RUN
        _write_labels(tmp / "labels.parquet", ds.t, labels)
        model.save(tmp / "model.json")
        if poses is not None and figures is not None:
            figures(tmp, ds, name, labels, poses, pose_source, training, metrics)
        with atomic_file(tmp / "labels-metrics.json") as js:
            js.write_text(json.dumps(metrics, indent=2, allow_nan=False) + "\n")


def _write_labels(path: Path, t: np.ndarray, labels: Labels) -> None:
    with atomic_file(path) as tmp:
        write_described(tmp, labels.frame(t), "labels")


def _metrics(
    ds: Dataset,
    model: FeatureModel,
    labels: Labels,
    pose_source: str,
    seconds: float,
    model_path: Path | None,
) -> dict[str, Any]:
    names, counts = np.unique(labels.label, return_counts=True)
    metrics: dict[str, Any] = {
        "scans": ds.n_scans,
        "classes": labels.classes,
        "model": str(model_path) if model_path else "learnt from the regions",
        "config": model.config.to_dict(),
        "temperature": model.temperature,
        "poses": pose_source,
        "label_counts": {str(n): int(c) for n, c in zip(names, counts, strict=True)},
        "mean_confidence": float(labels.confidence.mean()) if len(labels.label) else None,
        "seconds": round(seconds, 3),
    }
    return metrics


def _scores(truth: np.ndarray, labels: Labels, training: dict[str, np.ndarray]) -> dict[str, Any]:
    """Balanced accuracy, ECE and recall per class on every scan but the training ones."""
    test = np.ones(len(truth), dtype=bool)
    for idx in training.values():
        test[idx] = False
    correct = truth[test] == labels.label[test]
    return {
        "scored_scans": int(test.sum()),
        "balanced_accuracy": balanced_accuracy(truth[test], labels.label[test]),
        "ece": expected_calibration_error(labels.confidence[test], correct),
        "recall": per_class_recall(truth[test], labels.label[test]),
    }
