"""Parquet files describe themselves (units and meaning per column, the beam geometry of a
scans file), so that `pyarrow.parquet.read_schema` answers what meta.json answers; and every
option that takes a trajectory reads the TUM file `toolkit map` writes as well as Parquet."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from tests.conftest import ROOT, Cli
from toolkit.dataset import LaserGeometry, ScansWriter, load
from toolkit.errors import ToolkitError
from toolkit.trajio import read_trajectory, trajectory_format


def units(path: Path) -> dict[str, str]:
    schema = pq.read_schema(path)
    return {f.name: (f.metadata or {}).get(b"unit", b"?").decode() for f in schema}


def schema_meta(path: Path) -> dict[str, str]:
    return {k.decode(): v.decode() for k, v in (pq.read_schema(path).metadata or {}).items()}


def check_scans_match_meta(dataset: Path) -> None:
    meta = json.loads((dataset / "meta.json").read_text())
    scans = dataset / "scans.parquet"
    assert units(scans) == {"t": "s", "ranges": "m"}
    got = schema_meta(scans)
    laser = meta["laser"]
    assert int(got["beams"]) == laser["beams"] == meta["beams"]
    assert float(got["angle_min"]) == laser["angle_min"]
    assert float(got["angle_increment"]) == laser["angle_increment"]
    assert float(got["range_max"]) == laser["range_max"]
    assert json.loads(got["laser"]) == laser
    assert json.loads(got["source"])["format"] == meta["source"]["format"]
    assert (
        "NaN = no return" in pq.read_schema(scans).field("ranges").metadata[b"description"].decode()
    )
    assert json.loads(got["units"]) == {"t": "s", "ranges": "m"}


def check_poses(path: Path, kind: str) -> None:
    assert units(path) == {"t": "s", "x": "m", "y": "m", "theta": "rad"}
    got = schema_meta(path)
    assert got["toolkit_table"] == kind
    assert got["frame"]
    desc = pq.read_schema(path).field("theta").metadata[b"description"].decode()
    assert "counter-clockwise" in desc


def test_imported_carmen_dataset_describes_itself(cli: Cli, tmp_path: Path) -> None:
    out = tmp_path / "corridor"
    code, _, err = cli(
        "import", "carmen", ROOT / "datasets/corridor-carmen/sim.log.gz", "--out", out
    )
    assert code == 0, err
    check_scans_match_meta(out)
    check_poses(out / "odometry.parquet", "odometry")
    check_poses(out / "groundtruth.parquet", "groundtruth")
    assert "wheel odometry" in schema_meta(out / "odometry.parquet")["frame"]
    # the metadata does not change what is read
    ds = load(out)
    assert ds.ranges.shape == (2000, 181) and ds.odometry is not None


def test_streamed_rawseeds_dataset_describes_itself(cli: Cli, tmp_path: Path) -> None:
    out = tmp_path / "building"
    code, _, err = cli("import", "rawseeds", ROOT / "datasets/building-rawseeds", "--out", out)
    assert code == 0, err
    check_scans_match_meta(out)  # written batch by batch by ScansWriter
    check_poses(out / "odometry.parquet", "odometry")


def test_scans_writer_stores_a_geometry_known_only_at_the_end(tmp_path: Path) -> None:
    """Rawseeds' angular offset is decided by the whole log: close() puts it in the schema."""
    start = LaserGeometry.sick_180(181)
    path = tmp_path / "scans.parquet"
    writer = ScansWriter(path, 181, group=16, laser=start)
    writer.write(np.arange(40.0), np.full((40, 181), 2.5, np.float32))
    moved = LaserGeometry.from_dict({**start.to_dict(), "angle_min": start.angle_min + 0.01})
    writer.close(moved, {"format": "rawseeds", "file": "SICK_FRONT.csv"})
    got = schema_meta(path)
    assert float(got["angle_min"]) == moved.angle_min != start.angle_min
    assert units(path) == {"t": "s", "ranges": "m"}
    table = pq.read_table(path)
    assert table.num_rows == 40 and pq.ParquetFile(path).metadata.num_row_groups == 3
    assert float(table.schema.metadata[b"angle_min"]) == moved.angle_min


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A short simulated corridor (`toolkit simulate --format dataset`) and its odometry map run."""
    from toolkit.app.simulation import write_simulation
    from toolkit.mapping import map_run
    from toolkit.sim import simulate

    root = tmp_path_factory.mktemp("sim")
    data = root / "corridor"
    write_simulation(simulate("corridor", seed=3, scans=400), data, "dataset")
    run = map_run(data, root / "run", method="odometry").path
    return data, run


def test_run_and_simulation_tables_describe_themselves(sim_run: tuple[Path, Path]) -> None:
    data, run = sim_run
    check_scans_match_meta(data)
    check_poses(run / "trajectory.parquet", "trajectory")
    assert schema_meta(run / "trajectory.parquet")["method"] == "odometry"
    truth = units(data / "truth.parquet")
    assert truth["t"] == "s" and truth["x"] == "m" and truth["theta"] == "rad"


def test_label_reads_the_tum_trajectory_map_writes(sim_run: tuple[Path, Path], cli: Cli) -> None:
    data, run = sim_run
    tum, parquet = run / "trajectory.tum", run / "trajectory.parquet"
    assert trajectory_format(tum) == "tum" and trajectory_format(parquet) == "parquet"
    a, b = read_trajectory(tum), read_trajectory(parquet)
    assert len(a) == len(b) == 400
    np.testing.assert_allclose(a.to_numpy(), b.to_numpy(), atol=2e-6)  # TUM keeps 6-9 digits
    assert np.abs(b["theta"]).max() > 1.0  # the corridor's turn: the yaw really is read
    runs = {}
    for name, traj in (("tum", tum), ("parquet", parquet)):
        out = run.parent / f"labels-{name}"
        code, _, err = cli(
            "label", data, "--regions", data / "regions.csv", "--trajectory", traj, "--out", out
        )
        assert code == 0, err
        metrics = json.loads((out / "labels-metrics.json").read_text())
        assert metrics["poses"] == f"trajectory {traj}"
        runs[name] = pd.read_parquet(out / "labels.parquet")
    pd.testing.assert_frame_equal(runs["tum"], runs["parquet"], atol=1e-6)
    labels = out / "labels.parquet"
    got = units(labels)
    assert got["t"] == "s" and got["label"] == "" and got["p_none"] == "1"
    assert schema_meta(labels)["toolkit_table"] == "labels"


def test_trajectory_reader_errors_are_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "seven.tum"
    bad.write_text("# t x y z qx qy qz\n0 1 2 0 0 0 1\n1 1 2 0 0 0 1\n")
    with pytest.raises(ToolkitError, match="7 columns per line, expected 8") as e:
        read_trajectory(bad)
    assert str(bad) in str(e.value) and "\n" not in str(e.value)
    text = tmp_path / "text.tum"
    text.write_text("0 1 2 0 0 0 0 1\n1 one 2 0 0 0 0 1\n")
    with pytest.raises(ToolkitError, match="not a TUM trajectory"):
        read_trajectory(text)
    csv = tmp_path / "poses.csv"
    csv.write_text("t,x,y,theta\n0,1,2,0.5\n1,2,2,0.25\n")
    assert read_trajectory(csv)["theta"].tolist() == [0.5, 0.25]
    nocols = tmp_path / "t.parquet"
    pd.DataFrame({"t": [0.0], "x": [1.0]}).to_parquet(nocols)
    with pytest.raises(ToolkitError, match="lacks columns"):
        read_trajectory(nocols)
