"""Beams that read the robot itself (`toolkit.beams`): found from the odometry's turns, or
without odometry from scans far apart in time, and left out of `toolkit map`; never found on
the real logs."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import importers
import toolkit
from bench.robot_in_view import seeing_the_robot
from tests.conftest import Cli
from tests.slam.conftest import drifted_carmen
from toolkit import beams
from toolkit.beams import beam_spans, fixed_beams
from toolkit.metrics import evaluate
from toolkit.poses import odometry_poses, truth_poses
from toolkit.sim import simulate
from toolkit.slam.run import slam_trajectory

EDGE = 20  # beams at each edge of the 181-beam scan that see the robot's frame


def _seeing_the_robot(seed: int) -> toolkit.Dataset:
    """The simulated corridor whose EDGE first and last beams read the robot's frame at
    0.3 m (5 mm of range noise), as an LMS-200 mounted behind a bumper does."""
    return seeing_the_robot(simulate("corridor", seed=seed, scans=600).dataset, EDGE, seed)


def _odometry(ds: toolkit.Dataset) -> np.ndarray:
    odometry = odometry_poses(ds)
    assert odometry is not None
    return odometry


def test_beams_that_read_the_robot_are_left_out_and_the_map_holds(cli: Cli, tmp_path: Path) -> None:
    ds = _seeing_the_robot(0)
    found = fixed_beams(ds.ranges, _odometry(ds))
    edges = np.r_[0:EDGE, 181 - EDGE : 181]
    assert np.array_equal(found, edges)
    truth = truth_poses(ds)
    assert truth is not None
    kept, _ = slam_trajectory(ds)  # the mapper given every beam: held still by them
    assert evaluate(kept.poses, truth)["ate"]["rmse"] > 0.5
    toolkit.save(ds, tmp_path / "ds")
    code, out, err = cli("map", tmp_path / "ds", "--out", tmp_path / "run")
    assert code == 0, err
    assert "beams 0-19, 161-180 left out" in out
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["fixed_beams"] == edges.tolist()
    assert metrics["ate"]["rmse"] < 0.2


def test_a_log_seeing_only_the_world_keeps_every_beam() -> None:
    ds = simulate("building", seed=1, scans=600).dataset
    assert len(fixed_beams(ds.ranges, _odometry(ds))) == 0
    still = np.zeros((len(ds.t), 3))  # a robot that never turns: nothing is judged
    assert len(fixed_beams(_seeing_the_robot(1).ranges, still)) == 0


@pytest.mark.parametrize("name", ["acapulco", "infinite-corridor", "seattle"])
def test_real_no_beam_reads_the_robot(real: Path, name: str) -> None:
    """The three real logs nearest to the rule (seattle's beams agree across turns in up to
    0.10 of the pairs, infinite-corridor's 0.05, against 0.9), and acapulco's last beam,
    which reads 50.0 m in every scan: beyond the robot's reach, kept."""
    ds = drifted_carmen(real, name, seed=0)
    assert len(fixed_beams(ds.ranges, _odometry(ds))) == 0
    if name == "acapulco":
        assert np.all(ds.ranges[:, -1][np.isfinite(ds.ranges[:, -1])] == 50.0)


def test_without_odometry_the_beams_are_found_from_scans_far_apart() -> None:
    """A raw LMS-200 capture (no odometry) of the simulated corridor whose edge beams read the
    robot: found. The clean corridor keeps every beam, though the wall beside a robot that
    drives straight along it reads the same in 0.88 of the pairs (under APART_AGREE: judged
    at 0.85 it would go), and a robot that stood still tells nothing."""
    clean = replace(simulate("corridor", seed=0).dataset, odometry=None)
    seen = seeing_the_robot(clean, EDGE, 0)
    assert np.array_equal(fixed_beams(seen.ranges, None), np.r_[0:EDGE, 181 - EDGE : 181])
    assert len(fixed_beams(clean.ranges, None)) == 0
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(beams, "APART_AGREE", 0.85)
        assert len(fixed_beams(clean.ranges, None)) > 0
    rng = np.random.default_rng(0)
    still = np.repeat(seen.ranges[:1], 600, axis=0) + rng.normal(0, 0.005, (600, 181))
    assert len(fixed_beams(still.astype(np.float32), None)) == 0


@pytest.mark.parametrize(
    "source", ["seattle", "ccny_scan_tools_bags/laser_scan_sparsifier/demo.bag"]
)
def test_real_without_odometry_no_beam_reads_the_robot(real: Path, source: str) -> None:
    """Read without odometry, the real logs nearest to the rule: seattle's near beams read
    the same in up to 0.11 of the pairs far apart, the bag's (a robot that moved 6 cm) 0.69,
    against 0.95."""
    if source == "seattle":
        ds = drifted_carmen(real, source, seed=0)
    else:
        importer, paths = importers.resolve("auto", [real / source])
        ds = importer.read(paths, importers.read_options(importer, None))
        assert ds.odometry is None
    assert len(fixed_beams(ds.ranges, None)) == 0


def test_beam_spans() -> None:
    assert beam_spans([0, 1, 2, 5, 7, 8]) == "0-2, 5, 7-8"
    assert beam_spans([]) == ""


def test_the_bench_maps_a_world_seeing_the_robot(tmp_path: Path) -> None:
    """`python -m bench.robot_in_view`: the held-out table's command, on one world."""
    out = tmp_path / "robot_in_view.csv"
    subprocess.run(
        [sys.executable, "-m", "bench.robot_in_view", "--worlds", "418", "--edge", "20",
         "--no-kiss", "--out", str(out)],
        cwd=Path(__file__).resolve().parents[2], capture_output=True, text=True, check=True,
    )  # fmt: skip
    table = pd.read_csv(out)
    assert list(table["world"]) == ["corridor", "building"]
    assert (table["left_out"] == 40).all() and (table["clean_left_out"] == 0).all()
    assert (table["toolkit_map"] < 0.5).all() and (table["every_beam"] > 1.0).all()


def test_the_bench_maps_a_world_seeing_the_robot_without_odometry(tmp_path: Path) -> None:
    """`python -m bench.robot_in_view --no-odometry`: logs as raw LMS-200 captures, the mapper's
    constant velocity held still by the robot's beams (16-32 m) until they are left out; the
    map then as the narrower laser's (`narrow`), to the bit."""
    out = tmp_path / "robot_in_view.csv"
    subprocess.run(
        [sys.executable, "-m", "bench.robot_in_view", "--worlds", "2", "--edge", "20",
         "--no-kiss", "--no-odometry", "--out", str(out)],
        cwd=Path(__file__).resolve().parents[2], capture_output=True, text=True, check=True,
    )  # fmt: skip
    table = pd.read_csv(out)
    assert list(table["world"]) == ["corridor", "building"] and "odometry" not in table
    assert (table["left_out"] == 40).all() and (table["clean_left_out"] == 0).all()
    assert (table["toolkit_map"] < 0.3).all() and (table["every_beam"] > 5.0).all()
    assert (table["toolkit_map"] == table["narrow"]).all()


def test_ranges_in_millimetres_are_said_to_be_out_of_reach(cli: Cli, tmp_path: Path) -> None:
    """Every return beyond any laser's reach (a table read in metres that holds mm): nothing
    is matched, and the run says so instead of handing back the odometry as a map."""
    ds = simulate("corridor", seed=0, scans=300).dataset
    toolkit.save(replace(ds, ranges=ds.ranges * 1000), tmp_path / "mm")
    toolkit.save(ds, tmp_path / "m")
    code, out, err = cli("map", tmp_path / "mm", "--out", tmp_path / "run-mm")
    assert code == 0, err
    assert "100% of the returns beyond 100 m (ranges in cm or mm?" in out
    metrics = json.loads((tmp_path / "run-mm" / "metrics.json").read_text())
    assert metrics["beyond_reach"] == 1.0
    assert metrics["ate"]["rmse"] == pytest.approx(metrics["odometry"]["ate"]["rmse"], rel=0.05)
    code, out, _ = cli("map", tmp_path / "m", "--out", tmp_path / "run-m")
    assert code == 0 and "beyond 100 m" not in out
    assert "beyond_reach" not in json.loads((tmp_path / "run-m" / "metrics.json").read_text())
