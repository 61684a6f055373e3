"""Odometry that stands still while the robot moves (`toolkit.slam.stalls`): mended from the
scans by `toolkit map`, never on a robot that really stood still."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import importers
import toolkit
from bench.odometry_stalls import stalled
from importers.base import ImportOptions
from importers.rosbag.importer import RosbagOptions, RosbagWriteOptions
from tests.conftest import Cli
from toolkit import se2
from toolkit.dataset import PoseStream
from toolkit.metrics import evaluate
from toolkit.poses import odometry_poses, truth_poses
from toolkit.sim import simulate
from toolkit.slam.run import slam_trajectory
from toolkit.slam.stalls import MIN_STILL, mend_stalls, still_stretches


def test_a_bag_whose_odometry_stops_early_maps_from_its_scans(cli: Cli, tmp_path: Path) -> None:
    """The simulated corridor (1,200 scans) written as a ROS bag whose /odom stops after two
    thirds of the scans: the odometry is held at its last pose, and the mapper given it keeps
    the robot there (14 m off). `toolkit map` maps the last third from the scans."""
    ds = simulate("corridor", seed=0, scans=1200).dataset
    odometry = ds.stream("odometry")
    assert odometry is not None
    kept = 2 * len(odometry) // 3
    cut = replace(ds, odometry=PoseStream(odometry.t[:kept], odometry.xyt[:kept]))
    rosbag = importers.get("rosbag")
    bag = rosbag.read(rosbag.write(cut, tmp_path, RosbagWriteOptions(name="cut")), RosbagOptions())
    truth = truth_poses(bag)
    assert truth is not None
    held, _ = slam_trajectory(bag)
    assert evaluate(held.poses, truth)["ate"]["rmse"] > 5.0
    toolkit.save(bag, tmp_path / "ds")
    code, out, err = cli("map", tmp_path / "ds", "--out", tmp_path / "run")
    assert code == 0, err
    assert f"odometry still over scans {kept - 1}-{bag.n_scans - 1} while the scans moved" in out
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    (stall,) = metrics["odometry_stalls"]
    assert (stall["first"], stall["last"]) == (kept - 1, bag.n_scans - 1)
    assert stall["moved_m"] == pytest.approx(53.0, abs=2.0)  # the truth's: 53.1 m
    assert metrics["ate"]["rmse"] < 0.5
    assert metrics["odometry"]["ate"]["rmse"] > 5.0  # the logged odometry's, kept


def test_an_encoder_stalled_mid_log_is_mended_and_the_rest_continues() -> None:
    """The building (2,000 scans), its odometry frozen over the middle third and then going
    on from where it froze (the encoder counts again): each part of the log keeps its own."""
    ds = simulate("building", seed=1, scans=2000).dataset
    wheels, truth = odometry_poses(ds), truth_poses(ds)
    assert wheels is not None and truth is not None
    a, b = 666, 1333
    frozen = stalled(wheels, a, b)  # as the bench stalls it
    log = replace(ds, odometry=PoseStream(ds.t, frozen))
    mended, stalls = mend_stalls(log, frozen, still_stretches(frozen))
    assert [(s.first, s.last) for s in stalls] == [(a, b)]
    got = odometry_poses(mended)
    assert got is not None
    np.testing.assert_allclose(got[: a + 1], frozen[: a + 1])  # before: as logged
    after = se2.between(got[b:-1], got[b + 1 :])  # after: the odometry's own steps
    np.testing.assert_allclose(after, se2.between(frozen[b:-1], frozen[b + 1 :]), atol=1e-9)
    as_logged = evaluate(slam_trajectory(log)[0].poses, truth)["ate"]["rmse"]
    assert as_logged > 5.0
    assert evaluate(slam_trajectory(mended)[0].poses, truth)["ate"]["rmse"] < 0.2 * as_logged


@pytest.mark.parametrize(
    ("source", "options"),
    [
        ("csm_laserazos/laserazosSM3.log", {}),
        ("breezyslam_mines_urg04lx/exp1.dat", {"preset": "mines"}),
        ("breezyslam_mines_urg04lx/exp2.dat", {"preset": "mines"}),
    ],
)
def test_real_robots_that_stood_still_keep_their_odometry(
    real: Path, source: str, options: dict[str, str]
) -> None:
    """The real logs whose robots stop (laserazos for 14-22 scans, the Mines logs' for 11-20
    scans with an URG-04LX whose noise moves 2% of the beams 10 cm): their odometry is kept."""
    importer, paths = importers.resolve("auto" if not options else "table", [real / source])
    ds = importer.read(paths, importers.read_options(importer, ImportOptions(extra=options)))
    wheels = odometry_poses(ds)
    assert wheels is not None
    stretches = still_stretches(wheels)
    assert stretches  # the robot stops: looked at ...
    mended, stalls = mend_stalls(ds, wheels, stretches)
    assert stalls == [] and mended is ds  # ... and kept


def test_still_stretches() -> None:
    odometry = np.zeros((40, 3))
    odometry[:, 0] = np.arange(40) * 0.1
    odometry[5 : 5 + MIN_STILL, 0] = odometry[5, 0]  # scans 5..14 at one pose: MIN_STILL scans
    odometry[30 : 30 + MIN_STILL - 1] = odometry[30]  # one scan short
    assert still_stretches(odometry) == [(5, 5 + MIN_STILL - 1)]
    assert still_stretches(np.zeros((3, 3)), least=3) == [(0, 2)]
    assert still_stretches(np.zeros((1, 3))) == []
