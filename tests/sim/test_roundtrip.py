"""Every format with a writer: simulate, write, import back through the project's importer,
and find the same scans (to the format's precision), odometry and ground truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

import importers
from importers.base import Importer
from toolkit.app.simulation import write_simulation
from toolkit.dataset import Dataset, load
from toolkit.sim import Simulation, simulate

# format -> writer option sets worth a round trip each (any other writer: its defaults)
VARIANTS: dict[str, list[dict[str, Any]]] = {
    "aria": [{}, {"version": 2, "points": False}],
    "lms200": [
        {},
        {"units": "mm", "baud": 38400},
        {"noise_bytes": 3.0, "bit_error_rate": 2e-5, "truncate_last": True, "seed": 1},
    ],
    "rosbag": [{"version": "ros1"}, {"version": "ros2"}, {"version": "mcap"}],
}
# precision of what each format prints: time (s), range (m), pose x/y (m), theta (rad)
PRECISION = {"aria": (2e-6, 1.5e-3, 2e-4, 1e-4)}  # times are whole ms, which ARIA prints
DEFAULT_PRECISION = (2e-6, 1.5e-3, 1e-3, 1e-3)
CARRIES = {"lms200": 0, "table": 1}  # pose streams (odometry, ground truth); default both


def _writers() -> list[str]:
    return [n for n in importers.names() if type(importers.get(n)).write is not Importer.write]


CASES = [
    pytest.param(
        fmt, opts, id=f"{fmt}-{'-'.join(f'{k}={v}' for k, v in opts.items()) or 'default'}"
    )
    for fmt in _writers()
    for opts in VARIANTS.get(fmt, [{}])
]


@pytest.fixture(scope="module")
def sim() -> Simulation:
    # a short building log: corners, glass, columns, doors; 6 decimal timestamps
    return simulate("building", seed=3, scans=240)


def test_every_expected_writer_is_registered() -> None:
    assert {"carmen", "rawseeds", "aria", "lms200", "rosbag"} <= set(_writers())


@pytest.mark.parametrize(("fmt", "opts"), CASES)
def test_round_trip(sim: Simulation, fmt: str, opts: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "sim"
    files = write_simulation(sim, out, fmt, **opts)
    record = json.loads((out / "simulation.json").read_text())
    native = [out / f for f in record["files"]]
    assert native and all(p.exists() for p in native)
    assert {"truth.parquet", "regions.csv", "simulation.json"} <= {p.name for p in files}

    sources = [p for p in native if not p.name.endswith(".truth.json")]  # lms200's truth
    imported = load(importers.import_log(fmt, sources, tmp_path / "imported"))
    # auto-detection finds the format from the first native file, the truth files beside it
    # notwithstanding
    assert importers.detect([native[0]]).name == fmt

    src = sim.dataset
    keep = _kept_scans(src, imported, fmt, out)
    dt, dr, dxy, dth = PRECISION.get(fmt, DEFAULT_PRECISION)
    np.testing.assert_allclose(imported.t, src.t[keep], rtol=0, atol=dt)
    want = src.ranges[keep]
    if opts.get("units") == "mm":  # the 8 m mode cannot carry the 80 m mode's far readings
        assert imported.laser.range_max == pytest.approx(8.191)
        # 13-bit values from 0x1FF7 (8183 mm) up are error codes, never ranges
        want = np.where(want >= 8.183, np.nan, want)
    np.testing.assert_array_equal(np.isnan(imported.ranges), np.isnan(want))
    np.testing.assert_allclose(imported.ranges, want, rtol=0, atol=dr, equal_nan=True)
    assert imported.laser.beams == src.laser.beams
    assert imported.laser.angle_min == pytest.approx(src.laser.angle_min, abs=1e-6)
    assert imported.laser.angle_increment == pytest.approx(src.laser.angle_increment, abs=1e-6)

    carried = 0
    for name, theirs in (
        ("odometry", imported.odometry),
        ("groundtruth", imported.groundtruth if imported.groundtruth is not None
         else imported.poses.get("robotGlobal")),
    ):  # fmt: skip
        ours = getattr(src, name)
        if theirs is None:
            continue
        carried += 1
        _same_poses(theirs, ours, src.t[keep], dt, dxy, dth, f"{fmt} {name}")
    # a raw serial capture carries scans only, a table scans and odometry, the rest all three
    assert carried == CARRIES.get(fmt, 2), f"{fmt} carried {carried} pose streams"


def _kept_scans(src: Dataset, imported: Dataset, fmt: str, out: Path) -> np.ndarray:
    """Indices of the source scans the import holds: all, or the lms200 capture's intact ones."""
    if fmt != "lms200":
        assert imported.n_scans == src.n_scans
        return np.arange(src.n_scans)
    intact = np.array(json.loads((out / "capture.truth.json").read_text())["intact"])
    # the importer keeps every frame whose CRC holds: the intact ones (and nothing invented)
    index = np.searchsorted(src.t, imported.t - 1e-4)
    assert set(intact.tolist()) <= set(index.tolist())
    assert imported.report.records_kept >= len(intact)
    return index


def _same_poses(
    theirs: pd.DataFrame,
    ours: pd.DataFrame,
    t: np.ndarray,
    dt: float,
    dxy: float,
    dth: float,
    what: str,
) -> None:
    at = np.searchsorted(theirs.t.to_numpy(), t - dt)
    at = np.clip(at, 0, len(theirs) - 1)
    got = theirs.iloc[at]
    ref = ours.set_index("t").reindex(t, method="nearest")
    np.testing.assert_allclose(got.t, t, atol=dt, err_msg=what)
    np.testing.assert_allclose(got.x, ref.x, atol=dxy, err_msg=what)
    np.testing.assert_allclose(got.y, ref.y, atol=dxy, err_msg=what)
    err = np.angle(np.exp(1j * (got.theta.to_numpy() - ref.theta.to_numpy())))
    np.testing.assert_allclose(err, 0.0, atol=dth, err_msg=what)


def test_dataset_format_loads_directly(sim: Simulation, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    write_simulation(sim, out, "dataset")
    ds = load(out)
    np.testing.assert_array_equal(ds.ranges, sim.dataset.ranges)
    assert ds.groundtruth is not None and sim.dataset.groundtruth is not None
    pd.testing.assert_frame_equal(ds.groundtruth, sim.dataset.groundtruth)
    truth = pd.read_parquet(out / "truth.parquet")
    assert list(truth.columns) == ["t", "x", "y", "theta", "label", "section"]
    assert (truth.label.to_numpy() == sim.labels).all()
    regions = pd.read_csv(out / "regions.csv")
    assert list(regions.columns) == ["feature", "start", "end"]
    np.testing.assert_allclose(regions.start, sim.regions.start, atol=1e-6)
