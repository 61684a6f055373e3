"""`python -m bench.paired_maps`: the mapper's default against a variant on the same drifted
real logs, run by run, as each of its defaults was judged (docs/journal/maps.md)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from bench.paired_maps import drifted, variant
from importers.carmen import CarmenOptions
from toolkit import se2
from toolkit.poses import odometry_poses, truth_poses
from toolkit.typed import int_ranges

ROOT = Path(__file__).resolve().parents[2]


def test_settings_and_seeds_are_read_as_written() -> None:
    assert int_ranges("0-2,7") == (0, 1, 2, 7) and int_ranges("5") == (5,)
    config = variant(["loop.edge_check=0", "map.turn_tie=0.1", "slam.loops=false"])
    assert config.loop.edge_check == 0 and config.scan_map.turn_tie == 0.1 and not config.loops


def test_a_variant_is_paired_run_by_run(real: Path, tmp_path: Path) -> None:
    out = tmp_path / "paired.csv"
    done = subprocess.run(
        [sys.executable, "-m", "bench.paired_maps", "--logs", "intel", "--seeds", "0",
         "--set", "slam.loops=false", "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True, check=True,
        env={"TOOLKIT_REAL_DATA": str(real), "PATH": ""},
    )  # fmt: skip
    row = pd.read_csv(out).iloc[0]
    # without loops the Intel map keeps the front end's drift: larger, and no loop counted
    assert row["default_loops"] > 50 and row["variant_loops"] == 0
    assert row["variant_ate"] > row["default_ate"] and not row["equal"]
    assert "equal to the bit 0 / 1" in done.stdout and "intel 0:" in done.stdout


def test_an_unknown_setting_is_one_line() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "bench.paired_maps", "--set", "loop.nope=1"],
        cwd=ROOT, capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 1 and done.stderr.strip().endswith("(slam., loop. or map. NAME)")
    assert "Traceback" not in done.stderr


def test_the_simulator_is_paired_by_world(tmp_path: Path) -> None:
    out = tmp_path / "sim.csv"
    subprocess.run(
        [sys.executable, "-m", "bench.paired_maps", "--sim", "--logs", "building-lms200",
         "--seeds", "0", "--set", "slam.loops=false", "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True, check=True,
    )  # fmt: skip
    frame = pd.read_csv(out)
    # one world, one log asked for: the building without odometry closes its loops by default
    assert list(frame["log"]) == ["building-lms200"] and frame["seed"].tolist() == [0]
    row = frame.iloc[0]
    assert row["default_loops"] >= 5 and row["variant_loops"] == 0
    assert row["default_ate"] < row["variant_ate"] and row["default_false"] == 0


def test_the_mirrored_drift_turns_the_odometry_the_other_way(real: Path) -> None:
    """`--mirror`: every seed's odometry otherwise drifts one way (2% long, turning left); the
    mirror makes it 2% short and turning right, from the same seed's noise and slips."""
    read_as = CarmenOptions.parse({"poses": "groundtruth"})
    for mirror, longer in ((False, True), (True, False)):
        ((name, seed, ds),) = drifted(read_as, (0,), {"intel"}, mirror)
        odo, truth = odometry_poses(ds), truth_poses(ds)
        assert odo is not None and truth is not None and (name, seed) == ("intel", 0)
        path = np.hypot(*np.diff(odo[:, :2], axis=0).T).sum()
        true = np.hypot(*np.diff(truth[:, :2], axis=0).T).sum()
        assert (path > 1.01 * true) if longer else (path < 0.99 * true)
        turned = se2.wrap(np.diff(odo[:, 2])) - se2.wrap(np.diff(truth[:, 2]))
        assert (np.median(turned) > 0) == longer
