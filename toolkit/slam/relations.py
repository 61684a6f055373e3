"""The relation error of a run's trajectory (Kümmerle et al.): over the dataset's own
relations.parquet (Rawseeds' `.relations`) when it has one, else over relations derived from
the ground truth. Apart from `toolkit.slam.run`, so that every map run measures it without
loading the loop-closing pipeline (GTSAM, scipy.ndimage)."""

from __future__ import annotations

from typing import Any

import numpy as np

from toolkit import se2
from toolkit.dataset import Dataset
from toolkit.metrics import relation_error, relation_error_motions, truth_relations
from toolkit.poses import truth_poses

RELATIONS = "relations.parquet"


def relation_metrics(ds: Dataset, poses: np.ndarray) -> dict[str, Any] | None:
    """Relation error of `poses`: over the dataset's relations.parquet (Rawseeds' `.relations`,
    t1, t2, x, y, yaw: pose at t2 in the frame of t1) when it has one, else over relations
    derived from the truth; None without either."""
    path = ds.path / RELATIONS if ds.path is not None else None
    if path is not None and path.is_file():
        import pandas as pd  # noqa: PLC0415  (on use: only a Rawseeds log has the file)

        rel = pd.read_parquet(path)
        i = _nearest(ds.t, rel["t1"].to_numpy())
        j = _nearest(ds.t, rel["t2"].to_numpy())
        motion = rel[["x", "y", "yaw"]].to_numpy(np.float64)
        out = relation_error_motions(se2.between(poses[i], poses[j]), motion)
        return {"source": RELATIONS, **out}
    truth = truth_poses(ds)
    if truth is None:
        return None
    return {"source": "groundtruth", **relation_error(poses, truth, truth_relations(truth))}


def _nearest(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(t, q), 1, len(t) - 1)
    return np.where(np.abs(t[i - 1] - q) <= np.abs(t[i] - q), i - 1, i)
