"""CARMEN importer and writer: the real logs (Radish corrected, CSM, DP-SLAM), damaged copies
of a simulated log written by the writer, the writer -> reader round trip, and the CLI."""

from __future__ import annotations

import bisect
import bz2
import gzip
import math
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import importers
from importers.base import ImportOptions
from importers.carmen import (
    CODE_BAND,
    Carmen,
    CarmenOptions,
    CarmenWriteOptions,
    in_order,
    longest_in_order,
)
from tests.conftest import Cli
from tests.importers.checks import assert_bad_input_is_one_line
from toolkit.dataset import Dataset, LaserGeometry, load
from toolkit.errors import FormatError
from toolkit.sim import Simulation

RADISH = "carmen_radish_corrected"
RADISH_LOGS = [
    "acapulco",
    "belgioioso",
    "edmonton",
    "fhw",
    "freiburg-101",
    "freiburg-campus",
    "infinite-corridor",
    "intel",
    "orebro",
    "seattle",
]
LOGS = [f"{RADISH}/{n}-corrected.log.gz" for n in RADISH_LOGS] + [
    "csm_laserazos/laserazosSM3.log",
    "dpslam_loop5/loop5.log",
]
# the logs whose timestamps SOURCE.md calls broken (all 0, too few digits, garbage) or absent
NO_CLOCK = {"belgioioso", "freiburg-campus", "infinite-corridor", "orebro", "laserazosSM3", "loop5"}
# no-return codes SOURCE.md names for these logs
CODES = {
    "intel": 81.83,
    "belgioioso": 81.91,
    "seattle": 81.91,
    "freiburg-101": 81.91,
    "freiburg-campus": 81.91,
    "orebro": 32.767,
    "laserazosSM3": 7.999,
    "loop5": 8.191,
}
FOV_DEG = {181: 180.0, 180: 179.0, 361: 180.0, 360: 179.5}


def _short(rel: str) -> str:
    return Path(rel).name.removesuffix(".gz").removesuffix(".log").removesuffix("-corrected")


def _text_lines(path: Path) -> list[str]:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as f:
        return f.read().splitlines()


@dataclass
class Expected:
    """What SOURCE.md says about a log."""

    scans: int
    beams: int
    odom: int


def _source_table(real: Path) -> dict[str, Expected]:
    out = {}
    text = (real / RADISH / "SOURCE.md").read_text()
    for m in re.finditer(
        r"^\| (\S+)-corrected\.log\.gz \| \d+ \| (\d+) \| (\d+) \| (\d+) \|", text, re.M
    ):
        out[m[1]] = Expected(int(m[2]), int(m[4]), int(m[3]))
    csm = (real / "csm_laserazos" / "SOURCE.md").read_text()
    csm_m = re.search(r"(\d+) scans, (\d+) beams each", csm)
    assert csm_m, "csm SOURCE.md changed"
    out["laserazosSM3"] = Expected(int(csm_m[1]), int(csm_m[2]), 0)
    dp = (real / "dpslam_loop5" / "SOURCE.md").read_text()
    dp_m = re.search(r"(\d+) Odometry \+ (\d+) Laser lines", dp)
    assert dp_m and "Laser: 181 ranges" in dp, "dpslam SOURCE.md changed"
    out["loop5"] = Expected(int(dp_m[2]), 181, int(dp_m[1]))  # odom: the Odometry lines
    return out


@dataclass
class Parsed:
    path: Path
    lines: list[str]
    laser_lines: list[tuple[int, list[str]]]  # (1-based line number, tokens)
    ds: Dataset


@pytest.fixture(scope="module")
def parsed(real: Path) -> dict[str, Parsed]:
    """Every covered real log, parsed once, with its own text for independent checks."""
    out = {}
    reader = Carmen()
    for rel in LOGS:
        path = real / rel
        lines = _text_lines(path)
        laser = [
            (i, ln.split()) for i, ln in enumerate(lines, 1) if ln.startswith(("FLASER ", "Laser "))
        ]
        out[_short(rel)] = Parsed(path, lines, laser, reader.read([path], CarmenOptions()))
    return out


@pytest.fixture(scope="module")
def expected(real: Path) -> dict[str, Expected]:
    return _source_table(real)


NAMES = [_short(r) for r in LOGS]


# ---------------------------------------------------------------- real logs


@pytest.mark.parametrize("name", NAMES)
def test_counts_match_source_md_and_the_file(
    name: str, parsed: dict[str, Parsed], expected: dict[str, Expected]
) -> None:
    p, exp = parsed[name], expected[name]
    assert len(p.laser_lines) == exp.scans
    assert {int(tok[1]) for _, tok in p.laser_lines} == {exp.beams}
    ds = p.ds
    assert ds.n_beams == exp.beams
    late = ds.report.dropped.get("FLASER timestamp out of order", 0)
    assert ds.n_scans == exp.scans - late
    assert ds.report.records_read == exp.scans + exp.odom
    assert not {k for k in ds.report.dropped if "ODOM" not in k and "out of order" not in k}
    assert np.all(np.diff(ds.t) >= 0)
    assert math.isclose(np.rad2deg(ds.laser.fov), FOV_DEG[exp.beams], abs_tol=1e-9)
    assert math.isclose(np.rad2deg(ds.laser.angle_min), -90.0)


@pytest.mark.parametrize("name", NAMES)
def test_first_and_last_range_and_a_pose_match_the_text(
    name: str, parsed: dict[str, Parsed]
) -> None:
    p = parsed[name]
    ds = p.ds
    code = ds.meta["carmen"][f"{ds.meta['carmen']['primary_laser']}_no_return_from"]

    def expect(text: str) -> float:
        v = float(text)
        return math.nan if not math.isfinite(v) or v >= code else float(np.float32(v))

    first, last = p.laser_lines[0][1], p.laser_lines[-1][1]
    n = int(first[1])
    np.testing.assert_equal(ds.ranges[0, 0], expect(first[2]))
    np.testing.assert_equal(ds.ranges[0, 1], expect(first[3]))
    np.testing.assert_equal(ds.ranges[-1, -1], expect(last[1 + n]))
    # the robot pose of the 100th laser line, read from the text (DP-SLAM: the Odometry before)
    number, tokens = p.laser_lines[99]
    if tokens[0] == "Laser":
        pose = [float(v) for v in p.lines[number - 2].split()[1:4]]
    else:
        pose = [float(v) for v in tokens[2 + n + 3 : 2 + n + 6]]
    scan_poses = ds.poses.get("scan_pose", ds.odometry)
    assert scan_poses is not None
    row = scan_poses.iloc[99]
    assert row["t"] == ds.t[99]
    np.testing.assert_allclose(row[["x", "y", "theta"]].to_numpy(float), pose, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_clock_or_scan_order(name: str, parsed: dict[str, Parsed]) -> None:
    ds = parsed[name].ds
    if name in NO_CLOCK:
        assert ds.meta["time_source"] == "scan_order"
        np.testing.assert_array_equal(ds.t, np.arange(ds.n_scans, dtype=float))  # 1 Hz nominal
        assert any("scan order" in n and "1 Hz nominal" in n for n in ds.report.notes)
        # ODOM cannot be put on that time base: the laser lines' poses are the odometry
        assert ds.meta["carmen"]["odometry"].startswith("robot pose of the")
        assert ds.odometry is not None and len(ds.odometry) == ds.n_scans
    else:
        assert ds.meta["time_source"] == "log"
        stamps = [float(tok[-3]) for _, tok in parsed[name].laser_lines]
        assert ds.t[0] == stamps[0] and ds.t[-1] == stamps[-1]
        odom = [ln for ln in parsed[name].lines if ln.startswith("ODOM ")]
        assert (
            ds.odometry is not None
            and ds.meta["carmen"]["odometry"] == "ODOM lines at their own times"
        )
        assert len(ds.odometry) + ds.report.dropped.get("ODOM timestamp out of order", 0) == len(
            odom
        )
        assert np.all(np.diff(ds.odometry["t"].to_numpy()) >= 0)
        assert ds.groundtruth is None and len(ds.poses["scan_pose"]) == ds.n_scans


@pytest.mark.parametrize("name", NAMES)
def test_no_return_codes_become_nan(name: str, parsed: dict[str, Parsed]) -> None:
    p = parsed[name]
    ds = p.ds
    raw = np.array([tok[2 : 2 + ds.n_beams] for _, tok in p.laser_lines], dtype=float)
    top = np.nanmax(raw)
    if name in CODES:
        assert ds.laser.range_max == pytest.approx(CODES[name])
    finite = ds.ranges[np.isfinite(ds.ranges)]
    assert finite.max() < ds.laser.range_max * (1 - CODE_BAND)
    assert not np.any(ds.ranges == np.float32(top))
    # the code recurs in the file; every occurrence is NaN in the dataset
    assert (raw == ds.laser.range_max).sum() >= 5
    # NaN exactly where the file has a no-return or non-finite value (rows before intel's drops)
    code = ds.meta["carmen"][f"{ds.meta['carmen']['primary_laser']}_no_return_from"]
    k = min(290, ds.n_scans)
    no_return = ~np.isfinite(raw[:k]) | (raw[:k] >= code)
    np.testing.assert_array_equal(np.isnan(ds.ranges[:k]), no_return)
    assert 0.5 < np.isfinite(ds.ranges).mean() < 1.0


def test_intel_drops_the_four_scans_whose_timestamp_goes_back(parsed: dict[str, Parsed]) -> None:
    p = parsed["intel"]
    stamps = np.array([float(tok[-3]) for _, tok in p.laser_lines])
    back = np.flatnonzero(np.diff(stamps) < 0) + 1
    assert back.size == 4
    ds = p.ds
    assert ds.report.dropped["FLASER timestamp out of order"] == 4
    where = ds.report.examples["FLASER timestamp out of order"]
    assert where == f"{p.path}:{p.laser_lines[back[0]][0]}"
    keep = np.delete(np.arange(stamps.size), back)
    np.testing.assert_array_equal(ds.t, stamps[keep])  # file order kept, nothing re-sorted
    first_beam = np.array([float(p.laser_lines[k][1][2]) for k in keep], dtype=np.float32)
    first_beam[first_beam >= 81.83] = np.nan  # intel's no-return code
    np.testing.assert_array_equal(ds.ranges[:, 0], first_beam)


def test_poses_groundtruth_option_stores_the_corrected_poses(real: Path) -> None:
    path = real / RADISH / "intel-corrected.log.gz"
    ds = Carmen().read([path], CarmenOptions(poses="groundtruth"))
    assert ds.groundtruth is not None and len(ds.groundtruth) == ds.n_scans
    assert "scan_pose" not in ds.poses
    line = next(ln.split() for ln in _text_lines(path) if ln.startswith("FLASER "))
    np.testing.assert_array_equal(
        ds.groundtruth.iloc[0].to_numpy(), [float(line[-3])] + [float(v) for v in line[-6:-3]]
    )
    assert ds.meta["carmen"]["odometry"] == "ODOM lines at their own times"


def test_rate_option_sets_the_scan_order_clock(real: Path) -> None:
    ds = Carmen().read([real / RADISH / "orebro-corrected.log.gz"], CarmenOptions(rate=10.0))
    np.testing.assert_allclose(ds.t, np.arange(ds.n_scans) / 10.0)
    assert ds.meta["carmen"]["rate_hz"] == 10.0


def test_mounting_from_param(parsed: dict[str, Parsed]) -> None:
    # freiburg-101 says PARAM robot_frontlaser_offset -0.04; intel 0.0; its poses differ by 0
    assert parsed["freiburg-101"].ds.laser.x == -0.04
    assert parsed["intel"].ds.laser.x == 0.0
    assert any(
        "differs from the laser-robot pose" in n for n in parsed["freiburg-101"].ds.report.notes
    )


def _all_messages_log(path: Path) -> dict[str, np.ndarray]:
    """A log with every message this importer reads, from known values; returns the truth."""
    rng = np.random.default_rng(7)
    n_scan, beams = 12, 181
    t = 50.0 + 0.2 * np.arange(n_scan)
    robot = np.column_stack(
        [0.1 * np.arange(n_scan), 0.05 * np.arange(n_scan), 0.1 * np.arange(n_scan)]
    )
    front = rng.uniform(0.5, 20.0, (n_scan, beams)).round(3)
    rear = rng.uniform(0.5, 20.0, (n_scan, beams)).round(3)
    rl = rng.uniform(0.5, 10.0, (n_scan, 90)).round(3)
    rl[:, 5] = 30.0  # ROBOTLASER1 max_range: no return
    lines = [
        "# message formats defined: PARAM SYNC ODOM FLASER RLASER TRUEPOS ROBOTLASER1",
        "PARAM robot_frontlaser_offset 0.25 nohost 0",
        "PARAM robot_rearlaser_offset -0.2 nohost 0",
    ]

    def fmt(a: np.ndarray | list[float]) -> str:
        return " ".join(f"{v:.6g}" for v in a)

    for k in range(n_scan):
        x, y, th = robot[k]
        c, s_ = np.cos(th), np.sin(th)
        fpose = [x + 0.25 * c, y + 0.25 * s_, th]
        rpose = [x - 0.2 * c, y - 0.2 * s_, th + np.pi]
        stamp = f"{t[k]:.6f} host {t[k]:.6f}"
        lines += [
            f"ODOM {fmt(robot[k])} 0.1 0 0 {t[k] - 0.1:.6f} host {t[k] - 0.1:.6f}",
            "SYNC foo",
            f"FLASER {beams} {fmt(front[k])} {fmt(fpose)} {fmt(robot[k])} {stamp}",
            f"RLASER {beams} {fmt(rear[k])} {fmt(rpose)} {fmt(robot[k])} {stamp}",
            f"ROBOTLASER1 0 -0.785398 1.553343 0.017453 30.0 0.01 0 90 {fmt(rl[k])} 90 "
            f"{fmt(rl[k] * 100)} {fmt(fpose)} {fmt(robot[k])} 0.1 0 0.3 0.2 0 {stamp}",
            f"TRUEPOS {fmt(robot[k] + 1)} {fmt(robot[k])} {stamp}",
            "NEFF 3.5",
        ]
    path.write_text("\n".join(lines) + "\n")
    return {"t": t, "robot": robot, "front": front, "rear": rear, "rl": rl}


def test_every_message_of_a_known_log(tmp_path: Path) -> None:
    truth = _all_messages_log(tmp_path / "all.log")
    ds = Carmen().read([tmp_path / "all.log"], CarmenOptions())
    assert ds.meta["carmen"]["primary_laser"] == "FLASER"
    np.testing.assert_array_equal(ds.t, truth["t"])
    np.testing.assert_allclose(ds.ranges, truth["front"], rtol=1e-6)  # no code: nothing NaN
    assert ds.laser.range_max == pytest.approx(truth["front"].max())  # the largest reading
    assert ds.laser.x == 0.25 and ds.laser.y == 0.0 and ds.laser.yaw == 0.0
    rear = ds.lasers["rlaser"]
    np.testing.assert_allclose(rear.ranges, truth["rear"], rtol=1e-6)
    assert rear.laser.x == -0.2 and rear.laser.yaw == pytest.approx(np.pi, abs=1e-5)
    rl = ds.lasers["robotlaser1"]
    assert rl.laser.beams == 90 and rl.laser.range_max == 30.0
    assert rl.laser.angle_min == pytest.approx(-np.pi / 4, abs=1e-6)
    assert rl.laser.angle_increment == pytest.approx(np.pi / 180, abs=1e-6)
    expect = np.where(truth["rl"] >= 30.0, np.nan, truth["rl"]).astype(np.float32)
    np.testing.assert_array_equal(rl.ranges, expect)  # ranges, not the remissions after them
    assert ds.odometry is not None and ds.groundtruth is not None
    np.testing.assert_allclose(ds.odometry["t"], truth["t"] - 0.1)
    np.testing.assert_allclose(ds.groundtruth[["x", "y", "theta"]], truth["robot"] + 1, atol=1e-6)
    assert "skipped 12 NEFF line(s): not used" in ds.report.notes
    assert "skipped 12 SYNC line(s): not used" in ds.report.notes
    assert ds.report.records_read == 12 * 5 and ds.report.records_dropped == 0
    other = Carmen().read([tmp_path / "all.log"], CarmenOptions(laser="robotlaser1"))
    assert other.n_beams == 90 and set(other.lasers) == {"flaser", "rlaser"}


def _corrected_log(path: Path, laser_at: float) -> np.ndarray:
    """A corrected-style log: PARAM robot_frontlaser_offset -0.04, FLASER lines whose laser
    pose is the robot pose moved `laser_at` m along the heading (0: both fields equal, as a
    corrector writes them) and whose robot field is the pose itself; returns the poses."""
    k = np.arange(8.0)
    pose = np.column_stack([0.3 * k, 0.1 * k, 0.4 * k]).round(9)  # as printed
    lines = ["PARAM robot_frontlaser_offset -0.04 nohost 0"]
    for i, (x, y, th) in enumerate(pose):
        laser = [x + laser_at * np.cos(th), y + laser_at * np.sin(th), th]
        ranges = " ".join(["2.5"] * 181)
        lines.append(f"FLASER 181 {ranges} {' '.join(f'{v:.9f}' for v in laser)} "
                     f"{x:.9f} {y:.9f} {th:.9f} {i:.1f} pippo {i:.1f}")  # fmt: skip
    path.write_text("\n".join(lines) + "\n")
    return pose


def test_equal_poses_of_an_off_centre_laser_are_the_lasers(tmp_path: Path) -> None:
    """-O poses=groundtruth (equal_poses=laser, the default since session 34): where every
    line's laser and robot poses are equal while PARAM mounts the laser off centre (a
    corrector's log: belgioioso, freiburg-101, freiburg-campus), the poses are the laser's and
    the truth the robot's 0.04 m ahead of them (laser pose ∘ mounting⁻¹), the heading as
    written; a log whose laser pose is the robot pose moved by the mounting (a raw log),
    `-O laser_x=0`, `-O equal_poses=robot` (the reading before session 34) or poses=odometry
    keep the robot field as it is."""
    laser = CarmenOptions(poses="groundtruth")
    assert laser == CarmenOptions(poses="groundtruth", equal_poses="laser")
    pose = _corrected_log(tmp_path / "c.log", 0.0)
    ds = Carmen().read([tmp_path / "c.log"], laser)
    assert ds.laser.x == -0.04 and ds.groundtruth is not None
    ahead = pose[:, :2] + 0.04 * np.column_stack([np.cos(pose[:, 2]), np.sin(pose[:, 2])])
    np.testing.assert_allclose(ds.groundtruth[["x", "y"]], ahead, atol=1e-9)
    np.testing.assert_array_equal(ds.groundtruth["theta"], pose[:, 2])
    assert ds.meta["carmen"]["groundtruth"].startswith("laser pose of the FLASER lines, carried")
    assert ds.odometry is not None  # no ODOM: the lines are the odometry too, carried alike
    np.testing.assert_array_equal(ds.odometry.to_numpy(), ds.groundtruth.to_numpy())
    assert any("the poses are taken as the laser's" in n for n in ds.report.notes)
    for options in (
        CarmenOptions(poses="groundtruth", laser_x=0.0),
        CarmenOptions(poses="groundtruth", equal_poses="robot"),
        CarmenOptions(),
    ):
        kept = Carmen().read([tmp_path / "c.log"], options)
        stream = kept.groundtruth if kept.groundtruth is not None else kept.odometry
        assert stream is not None
        np.testing.assert_array_equal(stream[["x", "y", "theta"]].to_numpy(), pose)
    _corrected_log(tmp_path / "raw.log", -0.04)  # a raw log: the laser pose behind the robot
    raw = Carmen().read([tmp_path / "raw.log"], laser)
    assert raw.groundtruth is not None
    np.testing.assert_array_equal(raw.groundtruth[["x", "y", "theta"]].to_numpy(), pose)


# ---------------------------------------------------------------- damaged copies
# of a simulated log written by the CARMEN writer (its every line is known)


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory: pytest.TempPathFactory, corridor_sim: Simulation) -> Path:
    """The simulated corridor (2000 scans of 181 beams, odometry, truth) as a CARMEN log."""
    out = tmp_path_factory.mktemp("carmen-sim")
    (path,) = importers.get("carmen").write(corridor_sim.dataset, out)
    return Path(path)


@pytest.fixture(scope="module")
def sim_lines(sim_log: Path) -> list[str]:
    return _text_lines(sim_log)


def _write(tmp: Path, lines: list[str], name: str = "d.log", newline: bool = True) -> Path:
    path = tmp / name
    path.write_text("\n".join(lines) + ("\n" if newline else ""))
    return path


def _laser_numbers(lines: list[str]) -> list[int]:
    return [i for i, ln in enumerate(lines) if ln.startswith("FLASER ")]


def test_the_simulated_log_reads_whole(sim_lines: list[str], corridor_sim: Simulation) -> None:
    assert len(_laser_numbers(sim_lines)) == corridor_sim.dataset.n_scans == 2000
    assert sim_lines[_laser_numbers(sim_lines)[0]].startswith("FLASER 181 ")


def test_truncated_last_line_is_skipped_and_counted(tmp_path: Path, sim_lines: list[str]) -> None:
    k = _laser_numbers(sim_lines)[20]
    cut = [*sim_lines[:k], sim_lines[k][: len(sim_lines[k]) // 2]]
    ds = Carmen().read([_write(tmp_path, cut, newline=False)], CarmenOptions())
    assert ds.report.dropped == {"truncated last line": 1} | {
        k: v for k, v in ds.report.dropped.items() if k.startswith("ODOM")
    }
    assert ds.n_scans == 20
    assert ds.report.examples["truncated last line"].endswith(f":{k + 1}")


def test_wrong_number_of_ranges_is_skipped_with_its_line(
    tmp_path: Path, sim_lines: list[str]
) -> None:
    lines = list(sim_lines)
    k = _laser_numbers(lines)[5]
    tok = lines[k].split()
    lines[k] = " ".join(tok[:10] + tok[11:])  # n says 181, 180 values follow
    path = _write(tmp_path, lines)
    ds = Carmen().read([path], CarmenOptions())
    assert ds.report.dropped["wrong number of ranges"] == 1
    assert ds.report.examples["wrong number of ranges"] == f"{path}:{k + 1}"
    assert ds.n_scans == 1999
    assert float(tok[-3]) not in set(ds.t)


def test_non_numeric_value_is_skipped_with_its_line(tmp_path: Path, sim_lines: list[str]) -> None:
    lines = list(sim_lines)
    k = _laser_numbers(lines)[7]
    tok = lines[k].split()
    tok[50] = "1.2x"
    lines[k] = " ".join(tok)
    path = _write(tmp_path, lines)
    ds = Carmen().read([path], CarmenOptions())
    assert ds.report.dropped["non-numeric value"] == 1
    assert ds.report.examples["non-numeric value"] == f"{path}:{k + 1}"
    assert ds.n_scans == 1999


def test_nan_inf_and_negative_ranges_become_nan(
    tmp_path: Path, sim_lines: list[str], corridor_sim: Simulation
) -> None:
    lines = list(sim_lines)
    ranges = corridor_sim.dataset.ranges
    j = int(np.flatnonzero(np.isfinite(ranges[:, :4]).all(axis=1))[0])  # beams 0..3 return
    k = _laser_numbers(lines)[j]
    tok = lines[k].split()
    tok[2], tok[3], tok[4] = "nan", "inf", "-0.5"
    lines[k] = " ".join(tok)
    ds = Carmen().read([_write(tmp_path, lines)], CarmenOptions())
    assert np.isnan(ds.ranges[j, :3]).all()
    assert ds.ranges[j, 3] == np.float32(tok[5])
    assert "FLASER: 3 range values NaN, inf or negative -> NaN" in ds.report.notes
    assert ds.n_scans == 2000


def test_beam_count_changing_keeps_the_majority(tmp_path: Path, sim_lines: list[str]) -> None:
    lines = list(sim_lines)
    ks = _laser_numbers(lines)[10:13]
    for k in ks:
        tok = lines[k].split()
        lines[k] = " ".join(["FLASER", "182", *tok[2:183], "1.0", *tok[183:]])
    path = _write(tmp_path, lines)
    ds = Carmen().read([path], CarmenOptions())
    assert ds.n_beams == 181 and ds.n_scans == 1997
    assert ds.report.dropped["beam count 182 (the log's is 181)"] == 3
    assert ds.report.examples["beam count 182 (the log's is 181)"] == f"{path}:{ks[0] + 1}"


def test_compressed_damaged_copy(tmp_path: Path, sim_lines: list[str]) -> None:
    path = tmp_path / "sim.log.bz2"
    path.write_bytes(bz2.compress(("\n".join(sim_lines[:400]) + "\n").encode()))
    ds = Carmen().read([path], CarmenOptions())
    assert ds.n_scans == sum(ln.startswith("FLASER ") for ln in sim_lines[:400]) > 100
    assert Carmen().sniff(path)


def test_truncated_gzip_keeps_the_lines_before_the_damage(sim_log: Path, tmp_path: Path) -> None:
    data = gzip.compress(sim_log.read_bytes())
    path = tmp_path / "cut.log.gz"
    path.write_bytes(data[: len(data) // 2])
    ds = Carmen().read([path], CarmenOptions())
    assert 500 < ds.n_scans < 2000
    assert any("compressed stream is damaged" in n for n in ds.report.notes)
    assert ds.report.dropped.get("truncated last line", 0) <= 1


def test_range_max_option(real: Path) -> None:
    path = real / RADISH / "orebro-corrected.log.gz"
    off = Carmen().read([path], CarmenOptions(range_max="none"))
    assert np.isnan(off.ranges).sum() == 0 and np.nanmax(off.ranges) == np.float32(32.767)
    at30 = Carmen().read([path], CarmenOptions(range_max=30.0))
    assert at30.laser.range_max == 30.0
    np.testing.assert_array_equal(np.isnan(at30.ranges), off.ranges >= 30.0)


def test_a_stray_odom_timestamp_costs_one_line(tmp_path: Path) -> None:
    truth = _all_messages_log(tmp_path / "all.log")
    lines = (tmp_path / "all.log").read_text().splitlines()
    odom = [i for i, ln in enumerate(lines) if ln.startswith("ODOM ")]
    tok = lines[odom[3]].split()
    tok[7] = tok[9] = "4000000000.0"  # a garbage stamp, far in the future
    lines[odom[3]] = " ".join(tok)
    path = _write(tmp_path, lines)
    ds = Carmen().read([path], CarmenOptions())
    assert ds.report.dropped == {"ODOM timestamp out of order": 1}
    assert ds.report.examples["ODOM timestamp out of order"] == f"{path}:{odom[3] + 1}"
    assert ds.odometry is not None
    np.testing.assert_allclose(ds.odometry["t"], np.delete(truth["t"] - 0.1, 3))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 30), max_size=60))
def test_longest_in_order_drops_the_fewest(values: list[int]) -> None:
    stamp = np.array(values, dtype=float)
    keep = longest_in_order(stamp)
    assert np.all(np.diff(stamp[keep]) >= 0)
    assert keep.sum() >= in_order(stamp).sum()  # never worse than "drop what is below the max"
    # optimal: no longer non-decreasing run exists (patience sorting length, computed apart)
    tails: list[float] = []
    for v in values:
        tails[bisect.bisect_right(tails, v) : bisect.bisect_right(tails, v) + 1] = [v]
    assert keep.sum() == len(tails)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("", "empty file"),
        ("\n\n", "empty file"),
        ("ODOM 0 0 0 0 0 0 1.0 h 1.0\nODOM 1 0 0 0 0 0 2.0 h 2.0\n", "no laser lines"),
        ("# only a comment\nPARAM robot_frontlaser_offset 0.0 nohost 0\n", "no laser lines"),
        ("FLASER 3 1 2\nFLASER x 1 2 3\n", "no usable laser line: all 2 are damaged"),
    ],
)
def test_unusable_files_are_one_clear_error(tmp_path: Path, content: str, message: str) -> None:
    path = tmp_path / "bad.log"
    path.write_text(content)
    with pytest.raises(FormatError) as e:
        Carmen().read([path], CarmenOptions())
    assert message in e.value.line() and str(path) in e.value.line()
    assert "\n" not in e.value.line()


# ---------------------------------------------------------------- sniff


def test_sniff(real: Path, tmp_path: Path) -> None:
    carmen = Carmen()
    for rel in LOGS:
        assert carmen.sniff(real / rel), rel
    csv = tmp_path / "a.csv"
    csv.write_text("t,x,y\n1,2,3\n")
    blob = tmp_path / "b.bin"
    blob.write_bytes(bytes(range(256)) * 8)
    prose = tmp_path / "notes.txt"
    prose.write_text("Laser scanners are nice.\nOdometry drifts.\n")
    empty = tmp_path / "e.log"
    empty.write_text("")
    for path in (csv, blob, prose, empty, tmp_path):
        assert not carmen.sniff(path), path
    for rel in ("carmen_radish_corrected/intel-corrected.log.gz", "dpslam_loop5/loop5.log"):
        assert importers.detect([real / rel]).name == "carmen"


# ---------------------------------------------------------------- writer


def _synthetic(geometry: LaserGeometry, scans: int = 60, seed: int = 3) -> Dataset:
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.05, geometry.range_max * 1.2, (scans, geometry.beams))
    ranges[ranges >= geometry.range_max] = np.nan
    t = 1000.0 + np.cumsum(rng.uniform(0.05, 0.15, scans))
    to = np.linspace(t[0] - 0.5, t[-1] + 0.5, 5 * scans)
    odo = pd.DataFrame(
        {
            "t": to,
            "x": np.cos(to / 3),
            "y": np.sin(to / 3),
            "theta": (to / 3 + np.pi / 2 + np.pi) % (2 * np.pi) - np.pi,
        }
    )
    gt = pd.DataFrame({"t": t[::2], "x": 0.01 * np.arange(t[::2].size), "y": -2.0, "theta": 0.3})
    return Dataset(t, ranges.astype(np.float32), geometry, odometry=odo, groundtruth=gt)


@pytest.mark.parametrize(
    ("geometry", "message"),
    [
        (LaserGeometry.sick_180(181, range_max=30.0, x=0.12, y=-0.03, yaw=0.05), "FLASER 181 "),
        (LaserGeometry.sick_180(360, range_max=81.91, x=-0.04), "FLASER 360 "),
        (LaserGeometry(270, math.radians(-135), math.radians(1.0), 20.0, x=0.2), "ROBOTLASER1 "),
    ],
)
def test_writer_reader_round_trip(tmp_path: Path, geometry: LaserGeometry, message: str) -> None:
    ds = _synthetic(geometry)
    files = importers.get("carmen").write(ds, tmp_path / "out")
    assert files == [tmp_path / "out" / "sim.log"]
    text = files[0].read_text().splitlines()
    scans = [ln for ln in text if ln.startswith(message)]
    assert len(scans) == ds.n_scans
    assert re.search(r" \d+\.\d{6} toolkit \d+\.\d{6}$", scans[0])
    back = Carmen().read(files, CarmenOptions())
    assert back.laser.beams == geometry.beams
    for key in ("angle_min", "angle_increment", "x", "y", "yaw", "range_max"):
        assert getattr(back.laser, key) == pytest.approx(getattr(geometry, key), abs=1e-6), key
    np.testing.assert_array_equal(np.isnan(back.ranges), np.isnan(ds.ranges))
    np.testing.assert_allclose(back.ranges, ds.ranges, atol=1.5e-3)  # mm, 1 mm below range_max
    np.testing.assert_allclose(back.t, ds.t, atol=6e-7)
    assert back.odometry is not None and ds.odometry is not None
    np.testing.assert_allclose(back.odometry.to_numpy(), ds.odometry.to_numpy(), atol=6e-7)
    assert back.groundtruth is not None and ds.groundtruth is not None
    np.testing.assert_allclose(back.groundtruth.to_numpy(), ds.groundtruth.to_numpy(), atol=6e-7)
    # the robot pose in each laser line is the odometry interpolated at the scan time
    x = np.interp(ds.t, ds.odometry["t"], ds.odometry["x"])
    assert back.poses["scan_pose"]["x"].to_numpy() == pytest.approx(x, abs=1e-6)
    assert back.report.records_dropped == 0


@pytest.mark.parametrize("name", NAMES)
def test_real_log_write_read_round_trip(
    name: str, parsed: dict[str, Parsed], tmp_path: Path
) -> None:
    ds = parsed[name].ds
    files = Carmen().write(ds, tmp_path, CarmenWriteOptions(name=f"{name}.log"))
    back = Carmen().read(files, CarmenOptions())
    assert back.meta["time_source"] == "log"
    np.testing.assert_allclose(back.t, ds.t, atol=6e-7)
    np.testing.assert_array_equal(np.isnan(back.ranges), np.isnan(ds.ranges))
    np.testing.assert_allclose(back.ranges, ds.ranges, atol=1.5e-3)
    assert back.laser.x == ds.laser.x and back.laser.beams == ds.laser.beams
    assert back.odometry is not None and ds.odometry is not None
    np.testing.assert_allclose(back.odometry.to_numpy(), ds.odometry.to_numpy(), atol=6e-7)


def test_writer_leaves_nothing_half_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import importers.carmen as carmen

    ds = _synthetic(LaserGeometry.sick_180(181, range_max=30.0))
    out = tmp_path / "out"
    Carmen().write(ds, out)
    before = (out / "sim.log").read_bytes()

    def dies_half_way(ds: Dataset, path: Path, host: str = "") -> None:
        path.write_text("PARAM robot_frontlaser_offset 0.0 nohost 0\nFLASER 181 1.0")
        raise KeyboardInterrupt

    monkeypatch.setattr(carmen, "write_log", dies_half_way)
    with pytest.raises(KeyboardInterrupt):
        Carmen().write(ds, out)
    assert (out / "sim.log").read_bytes() == before
    assert sorted(p.name for p in out.iterdir()) == ["sim.log"]


# ---------------------------------------------------------------- CLI


def test_cli_import_carmen_and_auto(
    real: Path,
    tmp_path: Path,
    cli: Cli,
) -> None:
    out = tmp_path / "orebro"
    code, stdout, _ = cli("import", "carmen", str(real / RADISH / "orebro-corrected.log.gz"),
                           "--out", str(out), "-O", "poses=groundtruth", "--rate", "4")  # fmt: skip
    assert code == 0 and "237 x 181 beams" in stdout and "clock: scan_order" in stdout
    ds = load(out)
    assert ds.n_scans == 237 and ds.groundtruth is not None and ds.t[-1] == 236 / 4
    assert ds.meta["source"]["format"] == "carmen"
    out2 = tmp_path / "csm"
    code, stdout, _ = cli(
        "import",
        "auto",
        str(real / "csm_laserazos" / "laserazosSM3.log"),
        "--out",
        str(out2),
    )
    assert code == 0 and load(out2).ranges.shape == (778, 361)


@pytest.mark.parametrize("content", ["", "ODOM 0 0 0 0 0 0 1 h 1\n", "FLASER 5 1 2 3\n"])
def test_cli_bad_input_is_one_line_and_no_output(
    content: str,
    tmp_path: Path,
    cli: Cli,
) -> None:
    src = tmp_path / "bad.log"
    src.write_text(content)
    assert_bad_input_is_one_line(cli, "carmen", src, tmp_path)


def test_cli_subprocess_auto_on_dpslam(real: Path, tmp_path: Path) -> None:
    # the console script of the venv running the tests
    exe = Path(sys.executable).parent / "toolkit"
    out = tmp_path / "loop5"
    run = subprocess.run([str(exe), "import", "auto", str(real / "dpslam_loop5" / "loop5.log"), "--out", str(out)],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "551 x 181 beams" in run.stdout
    ds = load(out)
    assert ds.odometry is not None and len(ds.odometry) == 551
    first = (real / "dpslam_loop5" / "loop5.log").read_text().splitlines()[0].split()
    np.testing.assert_array_equal(
        ds.odometry.iloc[0][["x", "y", "theta"]].to_numpy(float), [float(v) for v in first[1:]]
    )


def test_dpslam_mounting_note_says_the_lines_carry_no_laser_pose(
    real: Path, tmp_path: Path
) -> None:
    """loop5's Laser lines repeat the Odometry pose: the note does not claim a mounting read
    from them (it said 'laser pose - robot pose in the laser lines') and names the README's
    0.40 m; -O laser_x=0.40 gives that mounting."""
    log = real / "dpslam_loop5" / "loop5.log"
    ds = load(importers.import_log("auto", [log], tmp_path / "a"))
    assert ds.laser.x == 0.0
    assert "Laser: mounting x 0 m (DP-SLAM lines carry no laser pose; its README's robot: " \
        "-O laser_x=0.40), y 0 m, yaw 0 rad" in ds.report.notes  # fmt: skip
    moved = load(
        importers.import_log(
            "auto", [log], tmp_path / "b", ImportOptions(extra={"laser_x": "0.40"})
        )
    )
    assert moved.laser.x == 0.4
    assert "Laser: mounting x 0.4 m (-O laser_x), y 0 m, yaw 0 rad" in moved.report.notes
    np.testing.assert_array_equal(moved.ranges, ds.ranges)
