"""`toolkit label`: learn (or load) a model, classify every scan, write the run's files.

RUN/ (created if needed; it may already hold `toolkit map`'s outputs):
    model.json           per feature, per beam: mean, variance, return probability; spans
    labels.parquet       t, p_<feature>... p_none, label
    membership.png       probability per feature along the map, and found / not found
    labels-cloud.ply     3D cloud, returns at the laser height, coloured by label
    labels-metrics.json  configuration, pose source, counts, timing (and scores vs truth)

Everything is computed first, then each file is written atomically.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from toolkit.atomic import atomic_file
from toolkit.dataset import Dataset, load
from toolkit.errors import ToolkitError
from toolkit.features.classify import Labels, classify
from toolkit.features.fitting import fit
from toolkit.features.metrics import (
    balanced_accuracy,
    expected_calibration_error,
    per_class_recall,
)
from toolkit.features.model import Config, FeatureModel
from toolkit.features.regions import read_regions, training_components, training_indices

OUTPUTS = ("model.json", "labels.parquet", "membership.png", "labels-cloud.ply")


def scan_poses(ds: Dataset, trajectory: Path | None = None) -> tuple[np.ndarray | None, str]:
    """Poses (S x 3) at the scan times: the given trajectory, else ground truth, else odometry."""
    frame: pd.DataFrame | None
    if trajectory is not None:
        try:
            frame = pd.read_parquet(trajectory)
        except (OSError, ValueError) as e:
            raise ToolkitError(f"cannot read trajectory: {e}", file=trajectory) from None
        missing = [c for c in ("t", "x", "y", "theta") if c not in frame.columns]
        if missing:
            raise ToolkitError(f"trajectory lacks columns {missing}", file=trajectory)
        source = f"trajectory {trajectory}"
    elif ds.groundtruth is not None and len(ds.groundtruth):
        frame, source = ds.groundtruth, "groundtruth"
    elif ds.odometry is not None and len(ds.odometry):
        frame, source = ds.odometry, "odometry"
    else:
        return None, "none (no poses: fixed switching per scan, no map figure)"
    frame = frame.sort_values("t")
    t = frame["t"].to_numpy(np.float64)
    theta = np.unwrap(frame["theta"].to_numpy(np.float64))
    poses = np.column_stack(
        [np.interp(ds.t, t, frame[c].to_numpy(np.float64)) for c in ("x", "y")]
        + [np.interp(ds.t, t, theta)]
    )
    return poses, source


def _truth_labels(ds: Dataset, truth: Path | None = None) -> np.ndarray | None:
    """True labels per scan: `truth` (t, label), else the simulator's truth.parquet when it
    sits beside the scans."""
    if truth is None:
        if ds.path is None or not (ds.path / "truth.parquet").exists():
            return None
        truth = ds.path / "truth.parquet"
    try:
        frame = pd.read_parquet(truth)
    except (OSError, ValueError) as e:
        raise ToolkitError(f"cannot read truth: {e}", file=truth) from None
    if "label" not in frame or "t" not in frame:
        raise ToolkitError("truth needs columns t and label", file=truth)
    t = frame["t"].to_numpy(np.float64)
    if len(t) != ds.n_scans or not np.allclose(t, ds.t, rtol=0, atol=1e-3):
        raise ToolkitError(
            f"truth has {len(t)} rows whose times do not match the dataset's {ds.n_scans} scans",
            file=truth,
        )
    return frame["label"].astype(str).to_numpy()


def label_run(
    dataset: Path,
    out: Path,
    regions: Path | None = None,
    model_path: Path | None = None,
    trajectory: Path | None = None,
    config: Config | None = None,
    force: bool = False,
    truth: Path | None = None,
) -> dict[str, Any]:
    """Learn from `regions` (or apply `model_path`), classify, write RUN; returns the metrics."""
    if regions is None and model_path is None:
        raise ToolkitError("give --regions REGIONS.csv to learn, or --model model.json to apply")
    existing = [name for name in OUTPUTS if (out / name).exists()]
    if existing and not force:
        raise ToolkitError(f"already holds {existing[0]}; pass --force to replace", file=out)
    ds = load(dataset)
    started = time.perf_counter()
    spans = read_regions(regions, ds.t) if regions is not None else []
    training = training_indices(spans) if spans else {}
    if model_path is not None:
        model = FeatureModel.load(model_path)
        model.check_laser(ds.laser, dataset)
        if config is not None:
            from dataclasses import replace

            model = replace(model, config=replace(model.config, smoothing=config.smoothing))
    else:
        model = fit(ds.ranges, ds.laser, training_components(spans), config or Config(), spans)
    poses, pose_source = scan_poses(ds, trajectory)
    labels = classify(model, ds.ranges, poses)
    seconds = time.perf_counter() - started
    metrics = _metrics(ds, model, labels, training, pose_source, seconds, model_path)
    truth_labels = _truth_labels(ds, truth)
    if truth_labels is not None:
        metrics["truth"] = _scores(truth_labels, labels, training)

    out.mkdir(parents=True, exist_ok=True)
    _write_labels(out / "labels.parquet", ds.t, labels)
    model.save(out / "model.json")
    if poses is not None:
        from toolkit.features.figures import membership_figure, write_cloud

        with atomic_file(out / "membership.png") as tmp:
            membership_figure(
                tmp, ds.ranges, poses, ds.laser, labels, training,
                title=f"{ds.path.name if ds.path else dataset}: feature membership ({pose_source})",
            )  # fmt: skip
        with atomic_file(out / "labels-cloud.ply") as tmp:
            metrics["cloud_points"] = write_cloud(tmp, ds.ranges, poses, ds.laser, labels)
    with atomic_file(out / "labels-metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=2, allow_nan=False) + "\n")
    return metrics


def _write_labels(path: Path, t: np.ndarray, labels: Labels) -> None:
    with atomic_file(path) as tmp:
        pq.write_table(pa.Table.from_pandas(labels.frame(t), preserve_index=False), tmp)


def _metrics(
    ds: Dataset,
    model: FeatureModel,
    labels: Labels,
    training: dict[str, np.ndarray],
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
    truth = _truth_labels(ds)
    if truth is not None:
        test = np.ones(len(truth), dtype=bool)
        for idx in training.values():
            test[idx] = False
        correct = truth[test] == labels.label[test]
        metrics["truth"] = {
            "scored_scans": int(test.sum()),
            "balanced_accuracy": balanced_accuracy(truth[test], labels.label[test]),
            "ece": expected_calibration_error(labels.confidence[test], correct),
            "recall": per_class_recall(truth[test], labels.label[test]),
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
