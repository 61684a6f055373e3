"""`toolkit label`'s truth (shared with the report): true labels matched to the scans by time."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from toolkit.dataset import Dataset, LaserGeometry
from toolkit.errors import ToolkitError
from toolkit.features.run import truth_labels


def scans(t: np.ndarray, path: Path | None = None) -> Dataset:
    ranges = np.full((len(t), 5), 2.0, dtype=np.float32)
    return Dataset(t=t, ranges=ranges, laser=LaserGeometry.sick_180(5), path=path)


def found(ds: Dataset, truth: pd.DataFrame | None = None) -> np.ndarray:
    labels = truth_labels(ds, truth)
    assert labels is not None
    return labels


def test_truth_labels_are_matched_by_time(tmp_path: Path) -> None:
    """A capture that lost frames keeps the true labels of the frames it has; a scan with no
    truth row near it means no truth (found) or an error (given)."""
    t = 100.0 + 0.2 * np.arange(10)
    labels = np.array(list("aaabbbccca"))
    truth = pd.DataFrame({"t": t, "label": labels})
    kept = np.array([0, 1, 4, 5, 9])
    assert list(found(scans(t[kept] + 1e-5), truth)) == list(labels[kept])
    with pytest.raises(ToolkitError, match="no row within 1 ms"):
        truth_labels(scans(np.array([100.1])), truth)
    # found inside the dataset folder, or beside it, without being named
    (tmp_path / "ds").mkdir()
    truth.to_parquet(tmp_path / "truth.parquet")
    assert list(found(scans(t, tmp_path / "ds"))) == list(labels)
    truth.iloc[::-1].to_parquet(tmp_path / "ds" / "truth.parquet")  # any row order
    assert list(found(scans(t[kept], tmp_path / "ds"))) == list(labels[kept])
    assert truth_labels(scans(np.array([100.1]), tmp_path / "ds")) is None
    assert truth_labels(scans(t)) is None  # in memory, nothing given
