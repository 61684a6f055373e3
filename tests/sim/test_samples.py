"""The committed samples in datasets/: the catalog names them, they import back to their
truth, their regions lie on their labels, and the generator reproduces them byte for byte."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import importers
from toolkit.app.samples import SAMPLES, make
from toolkit.dataset import load

DATASETS = Path(__file__).resolve().parents[2] / "datasets"
CATALOG = json.loads((DATASETS / "catalog.json").read_text())
ENTRIES = {e["name"]: e for e in CATALOG["samples"]}


def test_catalog_names_every_sample_with_its_files() -> None:
    assert set(ENTRIES) == {s.name for s in SAMPLES}
    assert {e["scenario"] for e in ENTRIES.values()} == {"corridor", "building"}
    total = 0
    for e in ENTRIES.values():
        for rel in [*(f"{e['path']}/{f}" for f in e["files"]), e["regions"], e["truth"]]:
            assert (DATASETS / rel).is_file(), rel
            total += (DATASETS / rel).stat().st_size
        assert len(e["features"]) >= 3
    assert total < 5_000_000  # a few MB in all


@pytest.mark.parametrize("name", sorted(ENTRIES))
def test_sample_imports_to_its_truth(name: str, tmp_path: Path) -> None:
    e = ENTRIES[name]
    folder = DATASETS / e["path"]
    source = folder if e["format"] == "rawseeds" else folder / e["files"][0]
    assert importers.detect([source]).name == e["format"]
    ds = load(importers.import_log("auto", [source], tmp_path / "ds"))
    truth = pd.read_parquet(DATASETS / e["truth"])
    assert len(truth) == e["scans"]
    # every imported scan is one of the truth's (lms200: the intact frames and no others)
    index = np.searchsorted(truth.t.to_numpy(), ds.t - 1e-3)
    np.testing.assert_allclose(truth.t.to_numpy()[index], ds.t, atol=1e-3)
    if e["format"] == "lms200":
        intact = json.loads((folder / "capture.truth.json").read_text())["intact"]
        assert set(intact) <= set(index.tolist()) and ds.n_scans < len(truth)
    else:
        assert ds.n_scans == len(truth)
        gt = ds.groundtruth if ds.groundtruth is not None else ds.poses["robotGlobal"]
        np.testing.assert_allclose(gt.x, truth.x, atol=1e-3)
        np.testing.assert_allclose(gt.y, truth.y, atol=1e-3)

    regions = pd.read_csv(DATASETS / e["regions"])
    assert sorted(regions.feature.unique()) == e["features"]
    t, labels = truth.t.to_numpy(), truth.label.to_numpy()
    starts, ends = regions.start.to_numpy(float), regions.end.to_numpy(float)
    for feature, start, end in zip(regions.feature, starts, ends, strict=True):
        inside = (t >= start) & (t <= end)
        assert inside.sum() == 5 and (labels[inside] == feature).all()
        # the imported log's own timestamps select the same scans (inclusive, exact)
        expected = np.isin(index, np.flatnonzero(inside)).sum()  # lms200: the intact ones
        assert ((ds.t >= start) & (ds.t <= end)).sum() == expected


def test_generator_reproduces_the_committed_bytes(tmp_path: Path) -> None:
    sample = next(s for s in SAMPLES if s.name == "corridor-lms200")  # the quickest
    make(tmp_path, [sample])
    for path in sorted((tmp_path / sample.name).iterdir()):
        committed = DATASETS / sample.name / path.name
        assert (
            hashlib.sha256(path.read_bytes()).hexdigest()
            == hashlib.sha256(committed.read_bytes()).hexdigest()
        ), path.name
