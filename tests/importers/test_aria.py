"""ARIA laser logs (.2d): hand-written logs with known ranges and poses, the writer -> reader
round trip for versions 2/3/4 with points and old sick1 ranges, damaged lines, damaged-input
properties, sniffing and the CLI.

No real ARIA log exists in ../shared/data/real, so the fixtures are written here."""

from __future__ import annotations

import gzip
import math
from functools import cache
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import importers
from importers.aria import Aria, AriaOptions, write
from tests.conftest import Cli
from tests.importers.checks import assert_bad_input_is_one_line
from toolkit.dataset import Dataset, LaserGeometry, load
from toolkit.errors import FormatError, ToolkitError

# Laser 100 mm ahead of the robot's centre, beams at -90, -45, 0, 45, 90 degrees; in each scan
# beam 0 reads 1 m, beam 1 nothing, beam 2 2 m, beam 3 sqrt(2) m, beam 4 0.5 m.
HAND_SCAN1 = """\
LaserOdometryLog
#Created by ArLaserLogger
version: 2
sick1pose: 100 0 0
sick1conf: -90 90 5
time: 10.000
robot: 1000 2000 90
scan1: 100 -1000  0 0  2100 0  1100 1000  100 500
cairn: GoalWithHeading 1000 2000 0 "" ICON_GOAL "goal1"
frobnicate: 1 2 3
time: 10.500
robot: 1100 2000 -45
robotGlobal: 1000 1990 90
scan1: 100 -1000  0 0  2100 0  1100 1000  100 500
"""
HAND_RANGES = [1.0, math.nan, 2.0, math.sqrt(2.0), 0.5]

HAND_SICK1 = """\
LaserOdometryLog
version: 3
scan1pose: 50 -20 380 180
sick1conf: -50 50 3
locationTypes: robot robotGlobal
logTime: 1.250
robot: 0 0 0
robotGlobal: 5 6 7
sick1: 1500 0 2500
logTime: 1.375
robot: 10 0 1
robotGlobal: 15 6 8
sick1: 1501 99999 2501
"""


def _read(path: Path, **extra: str) -> Dataset:
    return Aria().read([path], AriaOptions.parse(extra))


def test_hand_written_scan1_log(tmp_path: Path) -> None:
    path = tmp_path / "hand.2d"
    path.write_text(HAND_SCAN1)
    ds = _read(path)
    assert ds.ranges.shape == (2, 5)
    for row in ds.ranges:
        np.testing.assert_allclose(row, HAND_RANGES, rtol=1e-6, equal_nan=True)
    np.testing.assert_allclose(np.rad2deg(ds.angles), [-90, -45, 0, 45, 90])
    assert (ds.laser.x, ds.laser.y, ds.laser.yaw) == (0.1, 0.0, 0.0)
    np.testing.assert_array_equal(ds.t, [10.0, 10.5])
    odo = ds.odometry
    assert odo is not None
    np.testing.assert_allclose(odo[["x", "y", "theta"]].to_numpy(),
                               [[1.0, 2.0, math.pi / 2], [1.1, 2.0, -math.pi / 4]])  # fmt: skip
    glob = ds.poses["robotGlobal"]  # only the second scan has one
    np.testing.assert_allclose(glob.to_numpy(), [[10.5, 1.0, 1.99, math.pi / 2]])
    assert ds.groundtruth is None
    report = ds.meta["import_report"]
    assert report["records_kept"] == 2 and report["records_read"] == 3
    assert report["dropped"] == {"goal marker (cairn:) skipped": 1}
    assert report["notes"] == ["unknown tags ignored: frobnicate"]
    assert ds.meta["aria"]["version"] == "2" and ds.meta["time_source"].startswith("log")


def test_hand_written_sick1_log_with_version_3_header(tmp_path: Path) -> None:
    path = tmp_path / "old.2d"
    path.write_text(HAND_SICK1)
    ds = _read(path, range_max="50")
    np.testing.assert_allclose(ds.ranges, [[1.5, np.nan, 2.5], [1.501, np.nan, 2.501]],
                               rtol=1e-6, equal_nan=True)  # fmt: skip
    assert ds.laser.range_max == 50.0  # 99999 mm is beyond it: NaN
    assert (ds.laser.x, ds.laser.y, ds.laser.z) == (0.05, -0.02, 0.38)
    assert ds.laser.yaw == pytest.approx(math.pi)
    np.testing.assert_allclose(np.rad2deg(ds.angles), [-50, 0, 50])
    np.testing.assert_array_equal(ds.t, [1.25, 1.375])
    np.testing.assert_allclose(ds.poses["robotGlobal"][["x", "y"]].to_numpy(),
                               [[0.005, 0.006], [0.015, 0.006]])  # fmt: skip
    assert ds.meta["aria"]["laser_line"] == "sick1"


def _dataset(scans: int = 120, beams: int = 181, seed: int = 0) -> Dataset:
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.2, 30.0, (scans, beams)).astype(np.float32)
    ranges[:, 3] = np.nan
    ranges[rng.random((scans, beams)) < 0.05] = np.nan
    t = 50.0 + np.arange(scans) * 0.1
    heading = np.cumsum(rng.normal(0, 0.2, scans))
    odo = pd.DataFrame(
        {
            "t": t,
            "x": np.cumsum(np.cos(heading)) * 0.05,
            "y": np.cumsum(np.sin(heading)) * 0.05,
            "theta": np.angle(np.exp(1j * heading)),
        }
    )
    truth = odo.assign(x=odo["x"] * 1.02, y=odo["y"] - 0.1)
    laser = LaserGeometry.sick_180(beams, x=0.16, y=-0.01, z=0.31, yaw=np.deg2rad(2.0))
    return Dataset(t=t, ranges=ranges, laser=laser, odometry=odo, groundtruth=truth)


def _angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b)))))


@pytest.mark.parametrize("version", [2, 3, 4])
@pytest.mark.parametrize("points", [True, False])
def test_writer_reader_round_trip(tmp_path: Path, version: int, points: bool) -> None:
    ds = _dataset(beams=361 if points else 181)
    path = write(ds, tmp_path, version=version, points=points)
    assert path.name == "log.2d" and importers.detect([path]).name == "aria"
    back = _read(path)
    assert back.ranges.shape == ds.ranges.shape
    np.testing.assert_array_equal(np.isnan(back.ranges), np.isnan(ds.ranges))
    # integer mm: a point is off by at most 0.5 mm in x and y, a range by 0.5 mm
    tol = 0.5e-3 * (math.sqrt(2) if points else 1) + 1e-5
    np.testing.assert_allclose(back.ranges, ds.ranges, rtol=0, atol=tol)
    np.testing.assert_allclose(back.t, ds.t, rtol=0, atol=0.5e-3)  # ms, as ARIA prints
    assert back.laser.beams == ds.laser.beams
    np.testing.assert_allclose(back.angles, ds.angles, atol=1e-9)
    np.testing.assert_allclose([back.laser.x, back.laser.y, back.laser.yaw],
                               [0.16, -0.01, np.deg2rad(2.0)], atol=1e-9)  # fmt: skip
    assert back.laser.z == (0.0 if version == 2 else 0.31)  # version 2: sick1pose X Y TH
    for written, source in ((back.odometry, ds.odometry), (back.poses["robotGlobal"], ds.groundtruth)):  # fmt: skip
        assert written is not None and source is not None and len(written) == ds.n_scans
        np.testing.assert_allclose(written[["x", "y"]], source[["x", "y"]], rtol=0, atol=0.06e-3)
        assert _angle_diff(
            written["theta"].to_numpy(), source["theta"].to_numpy()
        ).max() < np.deg2rad(0.0006)
    assert back.groundtruth is None and back.meta["import_report"]["records_dropped"] == 0


def test_writer_pose_sources_and_no_odometry(tmp_path: Path) -> None:
    ds = _dataset(scans=20)
    stream = ds.groundtruth
    assert stream is not None
    no_odo = Dataset(t=ds.t, ranges=ds.ranges, laser=ds.laser, poses={"robotGlobal": stream})
    back = _read(write(no_odo, tmp_path / "a"))
    assert back.odometry is None
    np.testing.assert_allclose(back.poses["robotGlobal"]["x"], stream["x"], atol=0.06e-3)
    bare = Dataset(t=ds.t, ranges=ds.ranges, laser=ds.laser)
    text = write(bare, tmp_path / "b").read_text()
    assert "robot:" not in text and "robotGlobal:" not in text
    assert _read(tmp_path / "b" / "log.2d").poses == {}


def test_writer_refuses_unknown_options_and_versions(tmp_path: Path) -> None:
    ds = _dataset(scans=3)
    with pytest.raises(ToolkitError, match="unknown option"):
        write(ds, tmp_path, verison=3)
    with pytest.raises(ToolkitError, match="version must be 2, 3 or 4"):
        write(ds, tmp_path, version=5)
    assert list(tmp_path.iterdir()) == []


def _lines(ds: Dataset, tmp_path: Path) -> list[str]:
    return write(ds, tmp_path / "w").read_text().splitlines()


def test_damaged_lines_are_skipped_and_counted(tmp_path: Path) -> None:
    ds = _dataset(scans=30)
    lines = _lines(ds, tmp_path)
    scan_at = [i for i, line in enumerate(lines) if line.startswith("scan1:")]
    time_at = [i for i, line in enumerate(lines) if line.startswith("logTime:")]
    robot_at = [i for i, line in enumerate(lines) if line.startswith("robot:")]
    lines[scan_at[2]] = lines[scan_at[2]][: len(lines[scan_at[2]]) // 2]  # cut short
    lines[scan_at[5]] = lines[scan_at[5]].replace(" ", " x", 1)  # not a number
    lines[robot_at[7]] = "robot: 1 2"  # pose without heading
    lines[time_at[9]] = "logTime: 1.000"  # goes back
    lines[time_at[11]] = "logTime: nan"  # not a finite time
    lines.insert(scan_at[20], "cairn: Goal 0 0 0")
    path = tmp_path / "damaged.2d"
    path.write_text("\n".join(lines) + "\n")
    back = _read(path)
    report = back.meta["import_report"]
    assert report["dropped"] == {
        "scan1: not 362 numbers": 2,
        "robot: not X Y TH": 1,
        "time goes backwards": 1,
        "logTime: not a number": 1,
        "scan without time": 1,
        "goal marker (cairn:) skipped": 1,
    }
    kept = [i for i in range(30) if i not in (2, 5, 9, 11)]
    np.testing.assert_allclose(back.t, ds.t[kept], atol=0.5e-3)
    np.testing.assert_allclose(back.ranges, ds.ranges[kept], atol=1e-3)
    odo = back.odometry
    assert odo is not None and len(odo) == len(kept) - 1  # scan 7 has no odometry
    assert 7 not in np.rint((odo["t"].to_numpy() - 50.0) / 0.1).astype(int)
    assert report["examples"]["robot: not X Y TH"] == f"line {robot_at[7] + 1}"


def test_log_without_times_uses_scan_order_and_rate(tmp_path: Path) -> None:
    path = tmp_path / "untimed.2d"
    path.write_text(HAND_SICK1.replace("logTime", "velocities"))
    assert _read(path).t.tolist() == [0.0, 1.0]
    timed = Aria().read([path], AriaOptions(rate=4.0))
    assert timed.t.tolist() == [0.0, 0.25] and "4 Hz" in timed.meta["time_source"]


def test_compressed_log(tmp_path: Path) -> None:
    ds = _dataset(scans=40)
    data = write(ds, tmp_path / "w").read_bytes()
    (tmp_path / "log.2d.gz").write_bytes(gzip.compress(data))
    back = _read(tmp_path / "log.2d.gz")
    np.testing.assert_allclose(back.ranges, ds.ranges, atol=1e-3)
    cut = tmp_path / "cut.2d.gz"
    cut.write_bytes(gzip.compress(data)[: len(gzip.compress(data)) // 2])
    part = _read(cut)
    assert 0 < part.n_scans < ds.n_scans
    assert any("compressed stream damaged" in n for n in part.meta["import_report"]["notes"])


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("", "not an ARIA laser log"),
        ("Dear diary,\ntoday the robot drove.\n", "not an ARIA laser log"),
        ("time: 1\nrobot: 0 0 0\n", "not an ARIA laser log"),
        ("LaserOdometryLog\nversion: 4\nsick1conf: -90 90 181\n", "no intact scan"),
        ("LaserOdometryLog\nsick1conf: -90 90 100000000\nsick1: 1 2\n", r"N 2\.\.10000"),
        ("LaserOdometryLog\nsick1conf: 90 -90 181\nsick1: 1 2\n", "bad angles"),
        ("LaserOdometryLog\nsick1pose: 1 2\nsick1conf: -90 90 2\nsick1: 1 2\n", "laser pose"),
        ("LaserOdometryLog\nsick1conf: -90 90 3\nsick1: 1 2\nsick1: 1 2 3 4\n", "no intact scan"),
    ],
)
def test_unusable_files_are_one_clear_error(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / "bad.2d"
    path.write_text(content)
    with pytest.raises(FormatError, match=message) as info:
        _read(path)
    assert str(path) in info.value.line() and "\n" not in info.value.line()


@cache
def _sample() -> tuple[bytes, np.ndarray]:
    import tempfile

    ds = _dataset(scans=25, beams=91, seed=3)
    with tempfile.TemporaryDirectory() as d:
        return write(ds, Path(d)).read_bytes(), ds.ranges


_mutation = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0, 1)),
    st.tuples(st.just("flip"), st.lists(st.integers(0, 10**9), min_size=1, max_size=8)),
    st.tuples(st.just("prefix"), st.binary(min_size=1, max_size=200)),
    st.tuples(st.just("empty"), st.none()),
    st.tuples(st.just("count"), st.integers(-(10**12), 10**12)),
    st.tuples(st.just("lines"), st.lists(st.integers(0, 10**6), min_size=1, max_size=6)),
)


def _damage(data: bytes, kind: str, arg: object) -> tuple[bytes, int]:
    """Damaged bytes and how many scans the damage may alter (beyond dropping them)."""
    if kind == "truncate":
        return data[: int(len(data) * float(arg))], 0  # type: ignore[arg-type]
    if kind == "flip":
        buf = bytearray(data)
        header = data.index(b"scanId:")
        at = [(bit // 8) % len(buf) for bit in arg]  # type: ignore[attr-defined]
        for byte, bit in zip(at, arg, strict=True):  # type: ignore[call-overload]
            buf[byte] ^= 1 << (bit % 8)
        # a flip in the header (mounting, beam angles) may alter every scan
        return bytes(buf), len(data) if min(at) < header else 2 * len(at)
    if kind == "prefix":
        return bytes(arg) + data, 0  # type: ignore[call-overload]
    if kind == "empty":
        return b"", 0
    if kind == "count":
        return data.replace(b"sick1conf: -90 90 91", f"sick1conf: -90 90 {arg}".encode()), 0
    lines = data.split(b"\n")  # delete or duplicate lines; deleting header lines alters all
    header = lines.index(b"scanId: 1")
    alter = 0
    for k in arg:  # type: ignore[attr-defined]
        i = k % len(lines)
        alter += len(data) if i < header and k % 2 else 1
        lines = lines[:i] + lines[i + 1 :] if k % 2 else lines[: i + 1] + lines[i:]
    return b"\n".join(lines), alter


@settings(
    max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(mutation=_mutation)
def test_damaged_input_never_crashes_and_damage_stays_local(
    tmp_path: Path, mutation: tuple[str, object]
) -> None:
    data, rows = _sample()
    damaged, may_alter = _damage(data, *mutation)
    path = tmp_path / "damaged.2d"
    path.write_bytes(damaged)
    try:
        back = _read(path)
    except ToolkitError:
        return
    assert back.n_scans >= 1 and np.all(np.diff(back.t) >= 0)
    report = back.meta["import_report"]
    assert report["records_kept"] == back.n_scans <= report["records_read"]
    if back.n_beams != rows.shape[1]:
        return  # a flip in the header's beam count: every scan line is dropped but one kind
    with np.errstate(invalid="ignore"):
        close = np.abs(back.ranges[:, None, :] - rows[None, :, :]) <= 1e-3
    same = (close | (np.isnan(back.ranges)[:, None, :] & np.isnan(rows)[None, :, :])).all(-1)
    assert int(same.any(1).sum()) >= back.n_scans - may_alter


def test_a_last_line_cut_mid_number_is_dropped_and_counted(tmp_path: Path) -> None:
    """A log cut inside its last reading still parses (the number is only shorter): the line
    without its line end is the cut write, and it is dropped, not kept with a wrong range."""
    data, rows = _sample()
    path = tmp_path / "cut.2d"
    path.write_bytes(data[: len(data) - 3])
    back = _read(path)
    assert back.n_scans == len(rows) - 1
    np.testing.assert_allclose(back.ranges, rows[:-1], atol=1e-3)
    assert back.meta["import_report"]["dropped"] == {"truncated last line": 1}


def test_fatal_input_leaves_no_partial_dataset(tmp_path: Path) -> None:
    path = tmp_path / "bad.2d"
    path.write_text("LaserOdometryLog\nversion: 4\n")
    with pytest.raises(FormatError):
        importers.import_log("aria", [path], tmp_path / "out")
    assert [p.name for p in tmp_path.iterdir()] == ["bad.2d"]


# ---------------------------------------------------------------- sniffing and the CLI


def test_sniff(tmp_path: Path) -> None:
    path = write(_dataset(scans=5), tmp_path / "w")
    bare = tmp_path / "laser_log"  # no extension: the header tells
    bare.write_bytes(path.read_bytes())
    assert importers.detect([bare]).name == "aria"
    assert Aria().sniff(tmp_path / "w")  # the writer's directory
    old = tmp_path / "old.txt"
    old.write_text("# no magic line\nsick1conf: -90 90 3\nsick1: 1 2 3\n")
    assert Aria().sniff(old) and _read(old).n_scans == 1
    (tmp_path / "carmen.log").write_text("FLASER 3 1 2 3 0 0 0 0 0 0 1.0 host 1.0\n")
    (tmp_path / "capture.lms").write_bytes(bytes.fromhex("02 80 03 00 A0 00 10 16 0A") * 3)
    assert not Aria().sniff(tmp_path / "carmen.log")
    assert not Aria().sniff(tmp_path / "capture.lms")


def test_cli_import_aria_and_auto(tmp_path: Path, cli: Cli) -> None:
    ds = _dataset(scans=30)
    path = write(ds, tmp_path / "w", version=3)
    for fmt in ("aria", "auto"):
        out = tmp_path / fmt
        code, stdout, err = cli("import", fmt, str(path), "--out", str(out))
        assert code == 0, err
        assert "30 x 181 beams" in stdout and "robotGlobal: 30" in stdout
        back = load(out)
        assert (
            back.meta["source"]["format"] == "aria" and (out / "poses-robotGlobal.parquet").exists()
        )
        np.testing.assert_allclose(back.ranges, ds.ranges, atol=1e-3)


@pytest.mark.parametrize("content", ["", "just some text\nnothing to see\n"])
def test_cli_bad_input_is_one_line_and_no_output(
    content: str,
    tmp_path: Path,
    cli: Cli,
) -> None:
    src = tmp_path / "bad.2d"
    src.write_text(content)
    assert_bad_input_is_one_line(cli, "aria", src, tmp_path)
