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


def test_pose_tables_are_read_without_pandas_and_are_the_same_frames(tmp_path: Path) -> None:
    """`load` keeps the odometry and the ground truth as PoseStreams (numpy, no pandas) and
    makes them DataFrames on first use: the frames `read_poses` gives, normalised as a
    DataFrame given to a Dataset is."""
    from toolkit.dataset import GROUNDTRUTH, ODOMETRY, PoseStream, _poses_frame, read_poses

    ds = _dataset()
    rng, n = np.random.default_rng(1), ds.n_scans
    ds.odometry = pd.DataFrame(
        {"x": rng.normal(size=n), "t": ds.t, "theta": np.arange(n), "y": rng.normal(size=n)}
    )  # other column order, an int column: normalised
    toolkit.save(ds, tmp_path / "d")
    back = toolkit.load(tmp_path / "d")
    assert isinstance(back.__dict__["_odometry"], PoseStream)  # not made a frame yet
    odo = back.stream("odometry")
    assert odo is not None and np.array_equal(odo.t, ds.t)
    assert back.stream("groundtruth") is None and back.groundtruth is None
    expected = _poses_frame(read_poses(tmp_path / "d" / ODOMETRY))
    pd.testing.assert_frame_equal(back.odometry, expected, check_exact=True)
    assert back.odometry is back.odometry  # made once
    assert not (tmp_path / "d" / GROUNDTRUTH).exists()
    given = Dataset(ds.t, ds.ranges, ds.laser, odometry=PoseStream(ds.t, odo.xyt))
    pd.testing.assert_frame_equal(given.odometry, expected, check_exact=True)


def test_pose_table_is_from_pandas_own_table(tmp_path: Path) -> None:
    """`PoseStream.table` (no pandas) is `pa.Table.from_pandas(frame, preserve_index=False)`,
    schema metadata and all: the same Parquet bytes."""
    from toolkit.dataset import PoseStream, write_described

    rng = np.random.default_rng(2)
    for n in (0, 1, 7):
        stream = PoseStream(np.sort(rng.random(n)), rng.normal(size=(n, 3)))
        ours, theirs = stream.table(), pa.Table.from_pandas(stream.frame(), preserve_index=False)
        assert ours.equals(theirs) and ours.schema.equals(theirs.schema, check_metadata=True)
        write_described(tmp_path / "a.parquet", ours, "trajectory", method="gaussian")
        write_described(tmp_path / "b.parquet", stream.frame(), "trajectory", method="gaussian")
        assert (tmp_path / "a.parquet").read_bytes() == (tmp_path / "b.parquet").read_bytes()


def test_write_csv_is_pandas_to_csv(tmp_path: Path) -> None:
    """`write_csv` writes what `pd.DataFrame(rows).to_csv(index=False)` writes: bool, int,
    float (ints among floats, None as NaN, tiny and huge values), str (with commas and
    quotes) and mixed columns, and no rows at all."""
    from toolkit.dataset import write_csv

    rows = [
        {"a": 0, "x": 0.1, "f": 1, "ok": True, "why": "", "n": None, "m": np.float64(2.5)},
        {"a": 12, "x": 1e-7, "f": 2.5, "ok": False, "why": 'a, "b"', "n": 3.0, "m": True},
        {"a": 3, "x": 1e16, "f": np.nan, "ok": np.True_, "why": None, "n": None, "m": "s"},
        {"a": np.int64(4), "x": -0.0, "f": 7, "ok": True, "why": "fitness", "n": 1, "m": 1},
    ]
    for table in (rows, rows[:1], []):
        write_csv(tmp_path / "ours.csv", table, ["a", "x"])
        pd.DataFrame(table, columns=None if table else ["a", "x"]).to_csv(
            tmp_path / "pandas.csv", index=False
        )
        assert (tmp_path / "ours.csv").read_bytes() == (tmp_path / "pandas.csv").read_bytes()
