"""`table` importer and writer: round trips, units and layouts, MRPT-style two files with
odometry increments, the real BreezySLAM (Paris Mines) logs, sniffing, damaged tables."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import importers
from importers.table import TableOptions, TableWriteOptions
from tests.importers.checks import DAMAGES, damaged
from toolkit.dataset import Dataset, LaserGeometry
from toolkit.errors import FormatError, ToolkitError

TABLE = importers.get("table")
MINES = "breezyslam_mines_urg04lx"


def _dataset(scans: int = 40, beams: int = 181, seed: int = 1, fov: float = 180.0) -> Dataset:
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.1, 7.5, (scans, beams)).astype(np.float32)
    ranges[rng.random((scans, beams)) < 0.1] = np.nan
    t = 5000.0 + np.cumsum(rng.uniform(0.05, 0.15, scans))
    theta = np.angle(np.exp(1j * np.cumsum(rng.normal(0, 0.3, scans))))
    odo = pd.DataFrame(
        {"t": t, "x": rng.normal(0, 3, scans), "y": rng.normal(0, 3, scans), "theta": theta}
    )
    inc = math.radians(fov) / (beams - 1)
    laser = LaserGeometry(beams, -math.radians(fov) / 2, inc, 8.0, 0.05, x=0.2, z=0.3, yaw=0.01)
    return Dataset(t, ranges, laser, odometry=odo)


@pytest.mark.parametrize("sep", ["comma", "whitespace"])
def test_round_trip(tmp_path: Path, sep: str) -> None:
    ds = _dataset(beams=240, fov=240.0)
    (path,) = TABLE.write(ds, tmp_path, TableWriteOptions(sep=sep))
    assert TABLE.sniff(path) and importers.detect([path]).name == "table"
    back = TABLE.read([path], TableOptions())
    np.testing.assert_array_equal(back.ranges, ds.ranges)
    np.testing.assert_array_equal(back.t, ds.t)
    assert back.odometry is not None and ds.odometry is not None
    np.testing.assert_allclose(back.odometry.to_numpy(), ds.odometry.to_numpy(), rtol=0, atol=1e-12)
    assert back.laser == ds.laser
    assert back.report.records_read == back.report.records_kept == 40


def test_units_layout_and_angles_by_option(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    rows = 12
    t_ms = 1e6 + np.arange(rows) * 100.0
    ranges_mm = rng.integers(100, 30000, (rows, 271)).astype(float)
    ranges_mm[:, 5] = 0  # no return
    ranges_mm[:, 6] = 65535  # the sensor's error code
    pose = np.column_stack([np.arange(rows) * 0.5, np.zeros(rows), np.arange(rows) * 10.0])
    table = np.column_stack([t_ms, np.full(rows, 7), pose, ranges_mm])
    path = tmp_path / "scans.txt"
    np.savetxt(path, table, fmt="%.6f", delimiter="\t")
    opts = {
        "columns": "t,_,x,y,theta,ranges",
        "time_unit": "ms",
        "range_unit": "mm",
        "angle_unit": "deg",
        "fov": "270",
        "no_return": "0,65535",
        "sep": "tab",
    }
    ds = TABLE.read([path], TableOptions.parse(opts))
    np.testing.assert_allclose(ds.t, t_ms / 1000)
    assert ds.ranges.shape == (12, 271)
    assert np.isnan(ds.ranges[:, 5:7]).all()
    np.testing.assert_allclose(ds.ranges[:, 7], ranges_mm[:, 7] / 1000, rtol=1e-6)
    assert ds.laser.angle_min == pytest.approx(-math.radians(135))
    assert ds.laser.angle_increment == pytest.approx(math.radians(1.0))
    assert ds.odometry is not None
    np.testing.assert_allclose(ds.odometry.theta, np.angle(np.exp(1j * np.radians(pose[:, 2]))))
    assert ds.meta["table"]["invalid_readings"] == 24


def test_sick_default_and_header_row(tmp_path: Path) -> None:
    ranges = np.full((3, 181), 2.5)
    body = np.column_stack([[1.0, 2.0, 3.0], np.zeros((3, 3)), ranges])
    path = tmp_path / "plain.csv"
    head = ",".join(["t", "x", "y", "theta", *[f"r{i}" for i in range(181)]])
    np.savetxt(path, body, delimiter=",", header=head, comments="")
    ds = TABLE.read([path], TableOptions())
    assert ds.laser.angle_min == pytest.approx(-math.pi / 2)
    assert ds.laser.angle_increment == pytest.approx(math.radians(1))
    assert any("header" in n for n in ds.report.notes)
    assert any("SICK 180" in n for n in ds.report.notes)


def test_mrpt_style_two_files_with_odometry_increments(tmp_path: Path) -> None:
    ds = _dataset(scans=25, beams=361)
    odo = ds.odometry
    assert odo is not None
    x, y, th = (odo[c].to_numpy() for c in ("x", "y", "theta"))
    # increments in the frame of the previous pose, starting from the origin
    px, py, pth = np.r_[0, x[:-1]], np.r_[0, y[:-1]], np.r_[0, th[:-1]]
    c, s = np.cos(pth), np.sin(pth)
    dx, dy = c * (x - px) + s * (y - py), -s * (x - px) + c * (y - py)
    dth = np.angle(np.exp(1j * (th - pth)))
    laser_file = tmp_path / "run_LASER.txt"
    odo_file = tmp_path / "run_ODO.txt"
    np.savetxt(laser_file, np.nan_to_num(ds.ranges, nan=0.0), fmt="%.4f")
    np.savetxt(odo_file, np.column_stack([dx, dy, dth]), fmt="%.12f")
    assert TABLE.sniff(laser_file) and TABLE.sniff(odo_file)
    back = TABLE.read([odo_file, laser_file], TableOptions(rate=10.0))
    assert back.ranges.shape == (25, 361)
    assert back.laser.angle_increment == pytest.approx(math.radians(0.5))
    np.testing.assert_allclose(back.t, np.arange(25) / 10.0)
    assert back.odometry is not None
    np.testing.assert_allclose(back.odometry.x, x, atol=1e-9)
    np.testing.assert_allclose(back.odometry.y, y, atol=1e-9)
    np.testing.assert_allclose(np.exp(1j * back.odometry.theta), np.exp(1j * th), atol=1e-9)
    with pytest.raises(ToolkitError, match="--rate"):
        TABLE.read([laser_file, odo_file], TableOptions())


def test_rows_that_do_not_parse_are_dropped_and_counted(tmp_path: Path) -> None:
    ds = _dataset(scans=10, beams=20)
    (path,) = TABLE.write(ds, tmp_path)
    lines = path.read_text().splitlines()
    lines[3] = lines[3].rsplit(",", 5)[0]  # short row
    lines[6] = lines[6].replace(",", ",x7,", 1)  # long row with garbage
    lines[8] = lines[8].replace(",", ",oops,", 1).rsplit(",", 1)[0]  # garbage, right width
    path.write_text("\n".join(lines) + "\n")
    back = TABLE.read([path], TableOptions())
    assert back.n_scans == 7
    assert back.report.dropped == {"row that does not parse": 3}
    np.testing.assert_array_equal(back.t, ds.t[[0, 1, 3, 4, 6, 8, 9]])


# ---------------------------------------------------------------- real BreezySLAM logs


@pytest.mark.real
@pytest.mark.parametrize(("name", "scans"), [("exp1.dat", 756), ("exp2.dat", 641)])
def test_breezyslam_mines_logs(real: Path, name: str, scans: int) -> None:
    path = real / MINES / name
    assert TABLE.sniff(path)
    with pytest.raises(ToolkitError, match="preset=mines"):
        TABLE.read([path], TableOptions())
    ds = TABLE.read([path], TableOptions(preset="mines"))
    assert ds.ranges.shape == (scans, 682)
    text = path.read_text().splitlines()
    for row, line in ((0, text[0]), (-1, text[-1])):
        tokens = np.array(line.split(), dtype=float)
        assert tokens.size == 707
        mm = tokens[24:706]
        expect = np.where((mm == 0) | (mm < 20), np.nan, mm / 1000).astype(np.float32)
        np.testing.assert_array_equal(ds.ranges[row], expect)
        assert ds.t[row] == pytest.approx(tokens[0] / 1e6, abs=1e-9)
    assert ds.laser.fov == pytest.approx(math.radians(240))
    assert ds.laser.x == pytest.approx(0.145)
    # heading from the encoders: (right - left) ticks over the whole log, 2000 per revolution
    first, last = (np.array(text[i].split()[2:4], dtype=float) for i in (0, -1))
    turn = ((last[1] - first[1]) - (last[0] - first[0])) * 2 * math.pi * 0.077 / 2000 / 0.33
    assert ds.odometry is not None and len(ds.odometry) == scans
    assert math.cos(ds.odometry.theta.iloc[-1] - turn) == pytest.approx(1.0)
    assert 0.4 < float(np.isnan(ds.ranges).mean()) < 0.7  # SOURCE.md: 52% / 55% zeros


# ---------------------------------------------------------------- sniffing


def test_sniff_leaves_other_formats_alone(tmp_path: Path) -> None:
    sick = tmp_path / "a.csv"  # Rawseeds SICK layout: t, 181, offset, 181 ranges
    sick.write_text(",".join(["1234.5", "181", "0"] + ["1.5"] * 181) + "\n")
    named = tmp_path / "Bicocca_2009-02-27a-ODOMETRY_XYT.csv"
    named.write_text("\n".join(",".join(["1.0"] * 7) for _ in range(3)) + "\n")
    carmen = tmp_path / "log.clf"
    carmen.write_text("ODOM 1 2 3 0 0 0 10.0 host 10.0\n")
    short = tmp_path / "traj.txt"
    short.write_text("1 2 3 4\n5 6 7 8\n")
    for path in (sick, named, carmen, short):
        assert not TABLE.sniff(path), path.name


# ---------------------------------------------------------------- damaged input


@pytest.fixture(scope="module")
def clean_table(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    (path,) = TABLE.write(
        _dataset(scans=15, beams=30),
        tmp_path_factory.mktemp("t"),
        TableWriteOptions(sep="whitespace"),
    )
    return path.read_bytes()


@settings(
    max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    damage=st.sampled_from(DAMAGES),
    where=st.floats(0, 1),
    bit=st.integers(0, 7),
)
def test_damaged_tables_give_a_dataset_or_one_clear_error(
    tmp_path: Path, clean_table: bytes, damage: str, where: float, bit: int
) -> None:
    data = damaged(
        clean_table,
        damage,
        where,
        bit,
        b"\x00\xffgarbage 1 2\n",
        b" 99999999999999999999999 4294967295e300 ",
        insert=True,
    )
    path = tmp_path / f"x{hash((damage, where, bit))}.txt"
    path.write_bytes(data)
    try:
        ds = TABLE.read([path], TableOptions())
    except ToolkitError as e:
        assert "\n" not in e.line()
        return
    assert ds.n_scans > 0 and (np.diff(ds.t) >= 0).all()
    assert ds.report.records_kept + ds.report.records_dropped == ds.report.records_read


def test_cli_bad_table_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("a,b\nc,d\n")
    with pytest.raises(FormatError):
        TABLE.read([path], TableOptions())
    done = subprocess.run(
        [sys.executable, "-c", "from toolkit.app.cli import main; main()", "import", "table",
         str(path), "--out", str(tmp_path / "d")],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 1 and done.stderr.count("\n") == 1, done.stderr
    assert str(path) in done.stderr and not (tmp_path / "d").exists()
