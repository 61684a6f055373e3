"""Rawseeds importer and writer: the real Bicocca ground-truth files, a session whose SICK_FRONT
and odometry are written by our writer in the real 27a time range, damaged copies, bz2, CLI."""

from __future__ import annotations

import bz2
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

import importers
from importers import rawseeds
from importers.base import ImportOptions
from toolkit.dataset import Dataset, LaserGeometry, load, sha256
from toolkit.errors import FormatError, ToolkitError

SESSIONS = [
    "Bicocca_2009-02-25a",
    "Bicocca_2009-02-25b",
    "Bicocca_2009-02-26a",
    "Bicocca_2009-02-26b",
    "Bicocca_2009-02-27a",
]
S27 = "Bicocca_2009-02-27a"
GT_STREAMS = ["GROUNDTRUTH", "GT-extended", "GROUNDTRUTH-CARTOGRAPHER"]


def real_dir(real: Path, session: str) -> Path:
    return real / "rawseeds_bicocca_groundtruth" / session


def text_rows(path: Path) -> list[list[float]]:
    """The file's own text, parsed the plain Python way (the reference for the importer)."""
    rows = []
    for line in path.read_text().splitlines():
        if line.strip():
            rows.append([float(v) for v in line.replace(",", " ").split()])
    return rows


def synthetic(t0: float, scans: int = 300, seed: int = 0) -> Dataset:
    """A robot driving down a 3 m wide corridor at 0.5 m/s, SICK at 75 Hz: ranges to the walls
    (NaN beyond 30 m down the corridor: no return), odometry at 50 Hz."""
    rng = np.random.default_rng(seed)
    t = t0 + np.arange(scans) / 75.0
    angles = np.deg2rad(np.arange(-90.0, 91.0))
    y = 1.5 + 0.2 * np.sin(np.arange(scans) / 40.0)  # robot's offset from the right wall
    with np.errstate(divide="ignore"):
        to_left = np.where(np.sin(angles) > 1e-9, (3.0 - y[:, None]) / np.sin(angles), np.inf)
        to_right = np.where(np.sin(angles) < -1e-9, -y[:, None] / np.sin(angles), np.inf)
    ranges = np.minimum(to_left, to_right) + rng.normal(0, 0.01, (scans, 181))
    ranges[ranges > 30.0] = np.nan
    todo = np.arange(t0, t[-1], 1 / 50.0)
    odo = pd.DataFrame(
        {"t": todo, "x": 0.5 * (todo - t0), "y": 0.01 * (todo - t0), "theta": 0.001 * (todo - t0)}
    )
    return Dataset(t, ranges.astype(np.float32), LaserGeometry.sick_180(181), odometry=odo)


@pytest.fixture
def session(real: Path, tmp_path: Path) -> tuple[Path, Dataset]:
    """A 27a session dir: our SICK_FRONT and ODOMETRY_XYT plus the real GT files (copied to tmp)."""
    d = tmp_path / S27
    gt = pd.read_csv(real_dir(real, S27) / f"{S27}-GROUNDTRUTH.csv", header=None, nrows=1)
    ds = synthetic(float(gt.to_numpy()[0, 0]) + 10.0)
    rawseeds.write(ds, d, session=S27)
    for f in real_dir(real, S27).iterdir():
        shutil.copy(f, d / f.name)
    return d, ds


def sick_file(d: Path) -> Path:
    return d / f"{S27}-SICK_FRONT.csv"


def lines_of(path: Path) -> list[str]:
    return path.read_text().splitlines(keepends=True)


def run_import(src: Path | list[Path], out: Path, **opts: str) -> Dataset:
    laser = opts.pop("laser", None)
    sources = src if isinstance(src, list) else [src]
    importers.import_log("rawseeds", sources, out, ImportOptions(laser=laser, extra=opts))
    return load(out)


# ---------------------------------------------------------------- the real ground truth


@pytest.mark.parametrize("name", SESSIONS)
def test_real_groundtruth_of_every_session(real: Path, tmp_path: Path, name: str) -> None:
    src = real_dir(real, name)
    d = tmp_path / name
    gt_rows = text_rows(src / f"{name}-GROUNDTRUTH.csv")
    rawseeds.write(synthetic(gt_rows[0][0], scans=20), d, session=name)
    for f in src.iterdir():
        (d / f.name).symlink_to(f)  # referenced, not copied
    ds = run_import(d, tmp_path / "ds")

    checks = {
        "GROUNDTRUTH": ds.groundtruth,
        "GT-extended": ds.poses["gt-extended"],
        "GROUNDTRUTH-CARTOGRAPHER": ds.poses["cartographer"],
    }
    for stream, frame in checks.items():
        rows = text_rows(src / f"{name}-{stream}.csv")
        assert frame is not None and len(frame) == len(rows), stream
        for k in (0, -1):
            np.testing.assert_array_equal(frame.iloc[k].to_numpy(), rows[k][:4], err_msg=stream)
    relations = pq.read_table(tmp_path / "ds" / "relations.parquet").to_pandas()
    rel_rows = text_rows(src / f"{name}.relations")
    assert len(relations) == len(rel_rows)
    np.testing.assert_array_equal(relations.iloc[-1].to_numpy(), rel_rows[-1])
    meta = ds.meta["rawseeds"]
    assert meta["groundtruth"]["file"] == f"{name}-GROUNDTRUTH.csv"
    assert (
        "floor" in meta["groundtruth"]["frame"]
        and "part of the path" in meta["groundtruth"]["frame"]
    )
    assert meta["relations"]["pairs"] == len(rel_rows)
    assert ds.report.records_dropped == 0, ds.report.dropped
    if name == S27:  # the counts SOURCE.md documents
        assert ds.groundtruth is not None
        assert (len(ds.groundtruth), len(ds.poses["gt-extended"]), len(relations)) == (
            5940,
            7953,
            11111,
        )


def test_groundtruth_option_extended_and_none(
    session: tuple[Path, Dataset], tmp_path: Path
) -> None:
    d, _ = session
    ext = run_import(d, tmp_path / "ext", groundtruth="extended")
    first = text_rows(d / f"{S27}-GT-extended.csv")[0]
    assert ext.groundtruth is not None
    np.testing.assert_array_equal(ext.groundtruth.iloc[0].to_numpy(), first)
    assert len(ext.poses["gt-floor"]) == 5940
    assert ext.meta["rawseeds"]["groundtruth"]["file"] == f"{S27}-GT-extended.csv"
    none = run_import(d, tmp_path / "none", groundtruth="none")
    assert none.groundtruth is None
    with pytest.raises(ToolkitError, match="groundtruth=best"):
        run_import(d, tmp_path / "bad", groundtruth="best")
    assert not (tmp_path / "bad").exists()


# ---------------------------------------------------------------- a session written by us


def test_session_round_trip_to_written_precision(
    session: tuple[Path, Dataset], tmp_path: Path
) -> None:
    d, truth = session
    ds = run_import(d, tmp_path / "ds")
    assert ds.n_scans == truth.n_scans and ds.n_beams == 181
    np.testing.assert_allclose(ds.t, truth.t, rtol=0, atol=5e-7 + 2.5e-7)  # 6 decimals at 1e9 s
    both = np.isfinite(truth.ranges)
    assert np.array_equal(np.isnan(ds.ranges), ~both)  # no return written as 81.910, read as NaN
    assert np.abs(ds.ranges[both] - truth.ranges[both]).max() <= 0.0005 + 1e-5
    # exactly the numbers in the file's text
    first = [float(v) for v in lines_of(sick_file(d))[0].split(",")]
    expected = np.where(np.array(first[3:]) >= 81.83, np.nan, first[3:]).astype(np.float32)
    np.testing.assert_array_equal(ds.ranges[0], expected)
    assert ds.odometry is not None and truth.odometry is not None
    assert len(ds.odometry) == len(truth.odometry)
    np.testing.assert_allclose(
        ds.odometry[["x", "y", "theta"]], truth.odometry[["x", "y", "theta"]], atol=5e-4 + 1e-9
    )
    assert ds.laser == LaserGeometry.sick_180(181, range_max=81.83, x=0.08, y=0.0, z=0.45)
    assert math.isclose(ds.laser.angle_min, -math.pi / 2)
    assert ds.meta["source"]["format"] == "rawseeds" and ds.meta["session"] == S27
    sources = {Path(e["path"]).name: e for e in ds.meta["source"]["files"]}
    assert len(sources) == 6  # SICK, odometry, GT, GT-extended, relations, cartographer csv
    for name in (sick_file(d).name, f"{S27}-GROUNDTRUTH.csv"):
        assert sources[name]["sha256"] == sha256(d / name)
        assert sources[name]["bytes"] == (d / name).stat().st_size
    assert ds.report.records_read == ds.report.records_kept == truth.n_scans
    assert ds.report.records_dropped == 0
    readings = ds.meta["range_readings"]["sick_front"]
    assert readings["no_return"] == int((~both).sum()) > 0 and readings["invalid"] == 0
    assert ds.groundtruth is not None and len(ds.groundtruth) == 5940


def test_dataset_level_read_and_writer_checks(
    session: tuple[Path, Dataset], tmp_path: Path
) -> None:
    d, truth = session
    ds = importers.get("rawseeds").read([sick_file(d)], rawseeds.RawseedsOptions())
    assert ds.path is None and ds.n_scans == truth.n_scans and ds.odometry is None
    assert "no ODOMETRY_XYT file" in " ".join(ds.report.notes)
    narrow = Dataset(truth.t, truth.ranges[:, :180], LaserGeometry.sick_180(180))
    with pytest.raises(ToolkitError, match="181 beams at 1 deg"):
        rawseeds.write(narrow, tmp_path / "w")
    gt = truth.odometry
    assert gt is not None
    with_gt = Dataset(truth.t, truth.ranges, truth.laser, groundtruth=gt)
    files = rawseeds.write(with_gt, tmp_path / "w2")
    assert [f.name for f in files] == [
        "Sim_2026-01-01a-SICK_FRONT.csv",
        "Sim_2026-01-01a-GROUNDTRUTH.csv",
    ]
    first = lines_of(files[1])[0].rstrip("\n").split(",")
    assert len(first) == 13 and first[4:] == ["0.000000"] * 9
    assert first[0] == f"{gt.t[0]:.6f}" and first[1] == f"{gt.x[0]:.6f}"
    back = importers.get("rawseeds").read([tmp_path / "w2"], rawseeds.RawseedsOptions())
    assert back.groundtruth is not None
    np.testing.assert_allclose(back.groundtruth.to_numpy(), gt.to_numpy(), atol=5e-7 + 2.5e-7)


def test_other_lasers_and_laser_option(session: tuple[Path, Dataset], tmp_path: Path) -> None:
    d, truth = session
    rear = synthetic(truth.t[0] + 0.004, scans=150, seed=3)
    rawseeds.write(rear, tmp_path / "rear", session=S27)
    shutil.move(tmp_path / "rear" / f"{S27}-SICK_FRONT.csv", d / f"{S27}-SICK_REAR.csv")
    ds = run_import(d, tmp_path / "ds")
    assert ds.n_scans == truth.n_scans
    assert set(ds.lasers) == {"sick_rear"} and ds.lasers["sick_rear"].t.shape == (150,)
    g = ds.lasers["sick_rear"].laser
    assert (g.x, g.y, g.z, g.yaw) == (-0.463, 0.001, 0.454, math.pi)
    swapped = run_import(d, tmp_path / "swapped", laser="sick_rear")
    assert swapped.n_scans == 150 and swapped.laser.yaw == math.pi
    assert set(swapped.lasers) == {"sick_front"}
    with pytest.raises(
        FormatError,
        match=r"no HOKUYO_FRONT csv in session dir .*; it has sick_front, sick_rear \(--laser NAME\)$",
    ):
        run_import(d, tmp_path / "h", laser="hokuyo_front")


def test_bz2_session_equals_plain(session: tuple[Path, Dataset], tmp_path: Path) -> None:
    d, _ = session
    packed = tmp_path / "packed"
    packed.mkdir()
    for f in d.iterdir():
        (packed / (f.name + ".bz2")).write_bytes(bz2.compress(f.read_bytes()))
    plain = run_import(d, tmp_path / "plain")
    zipped = run_import(packed, tmp_path / "zipped")
    np.testing.assert_array_equal(zipped.ranges, plain.ranges)
    np.testing.assert_array_equal(zipped.t, plain.t)
    assert zipped.odometry is not None and plain.odometry is not None
    pd.testing.assert_frame_equal(zipped.odometry, plain.odometry)
    assert zipped.groundtruth is not None and plain.groundtruth is not None
    pd.testing.assert_frame_equal(zipped.groundtruth, plain.groundtruth)
    assert importers.get("rawseeds").sniff(packed)


def test_small_chunks_give_the_same_dataset(
    session: tuple[Path, Dataset], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    d, _ = session
    whole = run_import(sick_file(d), tmp_path / "whole")
    monkeypatch.setattr(rawseeds, "CHUNK_BYTES", 5000)  # a few lines per chunk
    small = run_import(sick_file(d), tmp_path / "small")
    np.testing.assert_array_equal(small.ranges, whole.ranges)
    np.testing.assert_array_equal(small.t, whole.t)


# ---------------------------------------------------------------- damaged input


def damaged(d: Path, tmp_path: Path, edit: object) -> Path:
    """A copy of the SICK file with its lines changed by `edit(lines)`."""
    lines = lines_of(sick_file(d))
    edit(lines)  # type: ignore[operator]
    out = tmp_path / "damaged" / f"{S27}-SICK_FRONT.csv"
    out.parent.mkdir(exist_ok=True)
    out.write_text("".join(lines))
    return out


def test_empty_file_is_a_clear_error(tmp_path: Path) -> None:
    empty = tmp_path / f"{S27}-SICK_FRONT.csv"
    empty.write_text("")
    with pytest.raises(FormatError) as e:
        run_import(empty, tmp_path / "ds")
    assert e.value.line() == f"{empty}: empty file"
    assert not (tmp_path / "ds").exists()
    assert not list(tmp_path.glob(".ds.*"))


def test_truncated_last_line_is_skipped_and_counted(
    session: tuple[Path, Dataset], tmp_path: Path
) -> None:
    d, truth = session

    def cut(lines: list[str]) -> None:
        lines[-1] = lines[-1][: len(lines[-1]) // 2]

    ds = run_import(damaged(d, tmp_path, cut), tmp_path / "ds")
    assert ds.n_scans == truth.n_scans - 1
    assert ds.report.dropped == {"truncated last line": 1}
    assert f"line {truth.n_scans}" in ds.report.examples["truncated last line"]


def test_wrong_number_of_ranges_and_n_ranges_field(
    session: tuple[Path, Dataset], tmp_path: Path
) -> None:
    d, truth = session

    def spoil(lines: list[str]) -> None:
        lines[9] = lines[9].rstrip("\n").rsplit(",", 1)[0] + "\n"  # 180 ranges
        lines[19] = lines[19].replace(",181,", ",180,", 1)  # field says 180, 181 given

    ds = run_import(damaged(d, tmp_path, spoil), tmp_path / "ds")
    assert ds.n_scans == truth.n_scans - 2
    assert ds.report.dropped == {
        "wrong number of ranges": 1,
        "n_ranges field does not match the ranges": 1,
    }
    assert f"line 10 (t={truth.t[9]:.6f})" in ds.report.examples["wrong number of ranges"]
    assert f"t={truth.t[19]:.6f}" in ds.report.examples["n_ranges field does not match the ranges"]
    assert truth.t[9] not in ds.t and truth.t[19] not in ds.t


@pytest.mark.parametrize("chunk", [None, 5000])
def test_non_numeric_value_names_file_and_line(
    session: tuple[Path, Dataset],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    chunk: int | None,
) -> None:
    d, _ = session
    if chunk:
        monkeypatch.setattr(rawseeds, "CHUNK_BYTES", chunk)

    def spoil(lines: list[str]) -> None:
        fields = lines[122].split(",")
        fields[50] = "1.2.3"
        lines[122] = ",".join(fields)

    bad = damaged(d, tmp_path, spoil)
    with pytest.raises(FormatError) as e:
        run_import(bad, tmp_path / "ds")
    assert e.value.line() == f"{bad}:123: non-numeric value '1.2.3' in field 51"
    assert not (tmp_path / "ds").exists()


def test_invalid_and_no_return_readings_become_nan(
    session: tuple[Path, Dataset], tmp_path: Path
) -> None:
    d, truth = session
    values = {3: "nan", 4: "inf", 5: "-1.500", 6: "0.000", 7: "81.910", 8: "81.830", 9: "81.820"}

    def spoil(lines: list[str]) -> None:
        fields = lines[0].rstrip("\n").split(",")
        for k, v in values.items():
            fields[k] = v
        lines[0] = ",".join(fields) + "\n"

    ds = run_import(damaged(d, tmp_path, spoil), tmp_path / "ds")
    assert np.isnan(ds.ranges[0, :6]).all() and ds.ranges[0, 6] == np.float32(81.82)
    readings = ds.meta["range_readings"]["sick_front"]
    written_nan = int((~np.isfinite(truth.ranges)).sum()) - int(
        (~np.isfinite(truth.ranges[0, :5])).sum()
    )
    assert readings["invalid"] == 3
    assert readings["no_return"] == written_nan + 3
    assert ds.report.records_dropped == 0 and ds.n_scans == truth.n_scans


@pytest.mark.parametrize("chunk", [None, 5000])
def test_out_of_order_scans_are_dropped_in_file_order(
    session: tuple[Path, Dataset],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    chunk: int | None,
) -> None:
    d, truth = session
    if chunk:
        monkeypatch.setattr(rawseeds, "CHUNK_BYTES", chunk)

    def spoil(lines: list[str]) -> None:
        lines[40] = lines[40].replace(lines[40].split(",")[0], f"{truth.t[10]:.6f}", 1)  # back
        lines[80] = lines[80].replace(lines[80].split(",")[0], f"{truth.t[-1] + 5:.6f}", 1)  # ahead

    ds = run_import(damaged(d, tmp_path, spoil), tmp_path / "ds")
    expected = np.delete(truth.t, [40, 80])
    np.testing.assert_allclose(ds.t, expected, atol=1e-6)
    assert ds.report.dropped == {"timestamp out of order": 2}
    assert np.all(np.diff(ds.t) >= 0)


def test_missing_odometry_and_missing_laser(session: tuple[Path, Dataset], tmp_path: Path) -> None:
    d, _ = session
    (d / f"{S27}-ODOMETRY_XYT.csv").unlink()
    ds = run_import(d, tmp_path / "ds")
    assert ds.odometry is None
    assert "no ODOMETRY_XYT file: imported without odometry" in ds.report.notes
    sick_file(d).unlink()
    with pytest.raises(FormatError, match=r"no SICK_FRONT csv in session dir"):
        run_import(d, tmp_path / "ds2")
    assert not (tmp_path / "ds2").exists()


def test_damaged_groundtruth_is_counted(session: tuple[Path, Dataset], tmp_path: Path) -> None:
    d, _ = session
    gt = d / f"{S27}-GROUNDTRUTH.csv"
    lines = lines_of(gt)
    lines[5] = "1235714876.4,1.0,2.0\n"
    gt.write_text("".join(lines)[:-20])
    ds = run_import(d, tmp_path / "ds")
    assert ds.report.dropped == {
        "GROUNDTRUTH: wrong number of fields": 1,
        "GROUNDTRUTH: truncated last line": 1,
    }
    assert ds.groundtruth is not None and len(ds.groundtruth) == 5940 - 2
    assert "line 6" in ds.report.examples["GROUNDTRUTH: wrong number of fields"]


# ---------------------------------------------------------------- sniffing and the CLI


def test_sniff(session: tuple[Path, Dataset], real: Path, tmp_path: Path) -> None:
    d, _ = session
    sniff = importers.get("rawseeds").sniff
    assert sniff(d) and sniff(sick_file(d)) and sniff(real_dir(real, S27))
    odd_name = tmp_path / "laser.log"
    shutil.copy(sick_file(d), odd_name)
    assert sniff(odd_name)
    assert importers.detect([odd_name]).name == "rawseeds"
    carmen = tmp_path / "robot.log"
    ranges = " ".join(["1.50"] * 181)
    carmen.write_text(
        "# CARMEN Logfile\nPARAM robot_front_laser_max 81.9 nohost 0\n"
        f"FLASER 181 {ranges} 0.0 0.0 0.0 0.0 0.0 0.0 1235714880.0 nohost 0.1\n"
    )
    assert not sniff(carmen)
    comma_carmen = tmp_path / "flaser.csv"
    comma_carmen.write_text("FLASER,181,0," + ",".join(["1.5"] * 181) + "\n")
    assert not sniff(comma_carmen)
    assert not sniff(tmp_path / "missing")
    real_carmen = sorted((real / "carmen_radish_corrected").glob("*.log.gz"))[:3]
    real_carmen += [
        real / "dpslam_loop5" / "loop5.log",
        real / "csm_laserazos" / "laserazosSM3.log",
    ]
    assert len(real_carmen) == 5 and all(p.is_file() for p in real_carmen)
    assert not any(sniff(p) for p in real_carmen)


def toolkit_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", "from toolkit.app.cli import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_cli_import_success_and_one_line_failure(
    session: tuple[Path, Dataset], tmp_path: Path
) -> None:
    d, truth = session
    ok = toolkit_cli("import", "auto", str(d), "--out", str(tmp_path / "ds"), "-q")
    assert ok.returncode == 0, ok.stderr
    assert json.loads((tmp_path / "ds" / "meta.json").read_text())["scans"] == truth.n_scans

    def spoil(lines: list[str]) -> None:
        lines[7] = lines[7].replace(",181,0,", ",181,x0,", 1)

    bad = damaged(d, tmp_path, spoil)
    out = tmp_path / "bad"
    res = toolkit_cli("import", "rawseeds", str(bad), "--out", str(out))
    assert res.returncode == 1
    assert res.stderr.splitlines() == [f"error: {bad}:8: non-numeric value 'x0' in field 3"]
    assert not out.exists() and not list(tmp_path.glob(".bad.*"))


def test_a_real_session_of_ground_truth_alone_says_so(real: Path, tmp_path: Path) -> None:
    """The real Bicocca folders hold ground truth only: `toolkit import auto` says what is
    there and that there are no scans, in one line, and writes nothing."""
    for name in SESSIONS:
        out = tmp_path / name
        res = toolkit_cli("import", "auto", str(real_dir(real, name)), "--out", str(out))
        assert res.returncode == 1
        assert res.stderr.splitlines() == [
            f"error: no SICK_FRONT csv in session dir {real_dir(real, name)}; it has "
            "GROUNDTRUTH-CARTOGRAPHER, GROUNDTRUTH, GT-extended, relations only: no laser "
            "scans to import"
        ]
        assert not out.exists()


def test_hokuyo_stream_geometry_and_error_codes(
    session: tuple[Path, Dataset], tmp_path: Path
) -> None:
    d, truth = session
    rng = np.random.default_rng(5)
    ranges = rng.uniform(0.1, 5.0, (40, 681)).round(3)
    ranges[:, 0] = 0.005  # URG-04LX error code (< 20 mm)
    ranges[:, 1] = 5.9  # beyond its 5.6 m
    t = truth.t[0] + np.arange(40) / 10.0
    np.savetxt(
        d / f"{S27}-HOKUYO_FRONT.csv", np.column_stack([t, ranges]), fmt="%.6f", delimiter=","
    )
    ds = run_import(d, tmp_path / "ds", laser="hokuyo_front")
    assert ds.n_scans == 40 and ds.n_beams == 681
    assert math.isclose(ds.laser.angle_increment, 2 * math.pi / 1024)
    assert math.isclose(ds.laser.angle_min, -340 * 2 * math.pi / 1024)
    assert np.isnan(ds.ranges[:, :2]).all()
    np.testing.assert_array_equal(ds.ranges[:, 2:], ranges[:, 2:].astype(np.float32))
    assert ds.meta["range_readings"]["hokuyo_front"]["no_return"] == 80
    assert set(ds.lasers) == {"sick_front"} and ds.lasers["sick_front"].t.shape == truth.t.shape


def test_files_of_two_sessions_are_refused(real: Path, tmp_path: Path) -> None:
    a = real_dir(real, SESSIONS[0]) / f"{SESSIONS[0]}-GROUNDTRUTH.csv"
    b = real_dir(real, S27) / f"{S27}-GT-extended.csv"
    with pytest.raises(FormatError, match="files of several sessions"):
        run_import([a, b], tmp_path / "ds")
    with pytest.raises(FormatError, match="no SICK_FRONT csv in given files"):
        run_import([b], tmp_path / "ds")


def test_truncated_and_corrupt_bz2(
    session: tuple[Path, Dataset], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    d, truth = session
    monkeypatch.setattr(rawseeds, "COMPRESSED_READ", 16384)  # the file is only ~0.5 MB
    packed = bz2.compress(sick_file(d).read_bytes(), compresslevel=1)  # 100 kB blocks
    cut = tmp_path / f"{S27}-SICK_FRONT.csv.bz2"
    cut.write_bytes(packed[: len(packed) // 2])
    ds = run_import(cut, tmp_path / "ds")
    assert 0 < ds.n_scans < truth.n_scans
    np.testing.assert_allclose(ds.t, truth.t[: ds.n_scans], rtol=0, atol=1e-6)
    assert ds.report.dropped.get("truncated last line", 0) <= 1
    assert f"{cut.name}: compressed stream ends early; imported what it held" in ds.report.notes
    spoiled = bytearray(packed)
    spoiled[len(packed) // 2 : len(packed) // 2 + 4] = b"\xff\x00\xff\x00"
    bad = tmp_path / "bad" / f"{S27}-SICK_FRONT.csv.bz2"
    bad.parent.mkdir()
    bad.write_bytes(bytes(spoiled))
    with pytest.raises(FormatError, match=r"-SICK_FRONT.csv.bz2: cannot decompress: bz2"):
        run_import(bad, tmp_path / "ds2")
    assert not (tmp_path / "ds2").exists()


def test_spaces_after_commas_and_crlf(session: tuple[Path, Dataset], tmp_path: Path) -> None:
    d, _ = session
    plain = run_import(sick_file(d), tmp_path / "plain")
    spaced = tmp_path / "spaced" / sick_file(d).name
    spaced.parent.mkdir()
    spaced.write_bytes(sick_file(d).read_bytes().replace(b",", b", ").replace(b"\n", b"\r\n"))
    odd = spaced.with_name("front.txt")
    shutil.copy(spaced, odd)
    assert importers.get("rawseeds").sniff(odd)  # the first line has the SICK layout
    ds = run_import(spaced, tmp_path / "ds")
    np.testing.assert_array_equal(ds.ranges, plain.ranges)
    np.testing.assert_array_equal(ds.t, plain.t)
