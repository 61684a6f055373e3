"""The dataset on disk: exact schema, round trip, atomic writes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import toolkit
from toolkit.atomic import atomic_dir, atomic_path
from toolkit.dataset import Dataset, LaserGeometry, ScansWriter, read_scans
from toolkit.errors import OutputExistsError


def _dataset(scans: int = 50, beams: int = 181) -> Dataset:
    rng = np.random.default_rng(0)
    ranges = rng.uniform(0.1, 30.0, (scans, beams)).astype(np.float32)
    ranges[3, 7] = np.nan
    t = 100.0 + np.arange(scans) / 75.0
    odo = pd.DataFrame({"t": t, "x": np.cumsum(np.full(scans, 0.01)), "y": 0.0, "theta": 0.0})
    return Dataset(t, ranges, LaserGeometry.sick_180(beams, x=0.08, z=0.45), odometry=odo)


def test_round_trip_keeps_every_value(tmp_path: Path) -> None:
    ds = _dataset()
    toolkit.save(ds, tmp_path / "d")
    back = toolkit.load(tmp_path / "d")
    np.testing.assert_array_equal(back.ranges, ds.ranges)  # NaN in the same place
    np.testing.assert_array_equal(back.t, ds.t)
    assert back.ranges.dtype == np.float32 and back.ranges.shape == (50, 181)
    pd.testing.assert_frame_equal(back.odometry, ds.odometry)
    assert back.groundtruth is None
    assert back.laser == ds.laser
    np.testing.assert_allclose(back.angles[[0, 90, 180]], np.deg2rad([-90, 0, 90]))


def test_scans_schema_is_the_contract(tmp_path: Path) -> None:
    toolkit.save(_dataset(beams=361), tmp_path / "d")
    schema = pq.read_schema(tmp_path / "d" / "scans.parquet")
    assert schema.field("t").type == pa.float64()
    assert schema.field("ranges").type == pa.list_(pa.float32(), 361)
    meta = json.loads((tmp_path / "d" / "meta.json").read_text())
    for key in ("angle_min", "angle_increment", "range_max", "x", "y", "z", "yaw"):
        assert key in meta["laser"]


def test_streaming_writer_matches_whole_write(tmp_path: Path) -> None:
    ds = _dataset(scans=1000)
    path = tmp_path / "s.parquet"
    with ScansWriter(path, ds.n_beams) as w:
        for k in range(0, 1000, 300):
            w.write(ds.t[k : k + 300], ds.ranges[k : k + 300])
    t, r = read_scans(path)
    np.testing.assert_array_equal(r, ds.ranges)
    np.testing.assert_array_equal(t, ds.t)


def test_interrupted_write_leaves_nothing(tmp_path: Path) -> None:
    out = tmp_path / "d"
    with pytest.raises(RuntimeError), atomic_dir(out) as tmp:
        (tmp / "scans.parquet").write_text("half")
        raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


def test_existing_output_needs_force(tmp_path: Path) -> None:
    toolkit.save(_dataset(), tmp_path / "d")
    with pytest.raises(OutputExistsError):
        toolkit.save(_dataset(), tmp_path / "d")
    toolkit.save(_dataset(scans=7), tmp_path / "d", force=True)
    assert toolkit.load(tmp_path / "d").n_scans == 7
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_outputs_get_ordinary_permissions(tmp_path: Path) -> None:
    import os
    import stat

    from toolkit.atomic import atomic_file

    mask = os.umask(0o022)
    try:
        toolkit.save(_dataset(), tmp_path / "d")
        with atomic_file(tmp_path / "f.txt") as tmp:
            tmp.write_text("x")
    finally:
        os.umask(mask)
    assert stat.S_IMODE((tmp_path / "d").stat().st_mode) == 0o755
    assert stat.S_IMODE((tmp_path / "f.txt").stat().st_mode) == 0o644


@pytest.mark.parametrize("kind", ["file", "directory"])
def test_atomic_path_replaces_a_file_or_directory_whole(tmp_path: Path, kind: str) -> None:
    out = tmp_path / "runs" / "log.bag"

    def make(path: Path, text: str) -> None:
        if kind == "file":
            path.write_text(text)
        else:
            path.mkdir()
            (path / "part").write_text(text)

    for text in ("old", "new"):
        with atomic_path(out) as path:
            assert not path.exists() and path.parent != out.parent
            make(path, text)
    assert (out.read_text() if kind == "file" else (out / "part").read_text()) == "new"
    with pytest.raises(RuntimeError), atomic_path(out) as path:
        make(path, "half")
        raise RuntimeError("interrupted")
    assert (out.read_text() if kind == "file" else (out / "part").read_text()) == "new"
    assert sorted(p.name for p in out.parent.iterdir()) == ["log.bag"]
