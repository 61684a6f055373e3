"""Logs without odometry: the simulator's corridor written as an LMS-200 capture and as a ROS
bag without odometry, imported and mapped (constant velocity, `toolkit.slam.localmap`), within
0.5 m ATE of the truth. Seeds 14 and 16 were not used for tuning (3-12 were; the bench's are
0-2); before the filtered velocity and the start velocity they mapped at 1.12 and 1.90 m."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import importers
import toolkit
from bench.lost_telegrams import captured
from tests.conftest import Cli
from toolkit import se2
from toolkit.align.scan import MatchConfig
from toolkit.app.simulation import write_simulation
from toolkit.dataset import load
from toolkit.metrics import evaluate
from toolkit.poses import truth_poses
from toolkit.sim import simulate
from toolkit.slam import localmap
from toolkit.slam.localmap import (
    MotionMatcher,
    sequential,
    standing,
    start_velocity,
    weighted_median,
)
from toolkit.slam.motion import jitters, on_slots, scan_clock
from toolkit.slam.run import slam_trajectory


def _mapped_ate(
    fmt: str, seed: int, tmp_path: Path, scenario: str = "corridor", scans: int | None = None
) -> float:
    sim = simulate(scenario, seed=seed, **({"scans": scans} if scans else {}))
    sim = replace(sim, dataset=replace(sim.dataset, odometry=None))
    out = tmp_path / "sim"
    if fmt == "rosbag":
        write_simulation(sim, out, fmt, version="ros1")
    else:
        write_simulation(sim, out, fmt)
    sources = [p for p in out.iterdir() if p.suffix in {".lms", ".bag"}]
    ds = load(importers.import_log(fmt, sources, tmp_path / "imported"))
    assert ds.odometry is None and ds.n_scans == sim.dataset.n_scans
    result, run = slam_trajectory(ds)
    assert run.metrics(ds)["motion_model"] == "constant velocity"
    truth = truth_poses(sim.dataset)
    assert truth is not None
    return float(evaluate(result.poses, truth)["ate"]["rmse"])


def _without_odometry(
    seed: int, scenario: str = "corridor"
) -> tuple[toolkit.Dataset, np.ndarray, float]:
    """World `seed`'s log without odometry, its truth and the robot's speed (m a scan, the
    median over the first 300 scans)."""
    ds = replace(simulate(scenario, seed=seed).dataset, odometry=None)
    truth = truth_poses(ds)
    assert truth is not None
    speed = float(np.median(np.hypot(*np.diff(truth[:300, :2], axis=0).T)))
    return ds, truth, speed


def test_lms200_capture_of_the_corridor_maps_within_half_a_metre(tmp_path: Path) -> None:
    assert _mapped_ate("lms200", 16, tmp_path) <= 0.5


def test_bag_without_odometry_of_the_corridor_maps_within_half_a_metre(tmp_path: Path) -> None:
    assert _mapped_ate("rosbag", 14, tmp_path) <= 0.5


@pytest.mark.parametrize(
    ("scenario", "fmt", "seed"),
    [("corridor", "lms200", 11), ("building", "rosbag", 3), ("corridor", "lms200", 53)],
)
def test_logs_that_lost_speed_along_a_corridor_map_within_half_a_metre(
    scenario: str, fmt: str, seed: int, tmp_path: Path
) -> None:
    # development seeds (0-14) that missed 0.5 m before the forward probe: corridor seed 11 at
    # 0.76 m, building seed 3 at 0.58 m (the velocity random-walked down along a corridor);
    # corridor seed 53 (a spent held-out seed) at 1.98 m before the start velocity was weighed
    # by the probe's response (its first pass parked: start speed 0.002 m a scan of 0.080)
    assert _mapped_ate(fmt, seed, tmp_path, scenario) <= 0.5


def test_the_speed_resumes_after_a_turn_on_the_spot(tmp_path: Path) -> None:
    """The building at 2,000 scans (7 cm apart) as an LMS-200 capture: a turn on the spot at a
    corner took the velocity's forward part to about zero, and the bare stretch after it held
    it there for some 300 scans (world 1 lost 3.2 m after one corner and mapped 0.89 m off;
    development worlds 0-15 0.59 m on average). Resumed at the speed before the turn: 0.12 m."""
    assert _mapped_ate("lms200", 1, tmp_path, "building", scans=2000) <= 0.2


def test_a_capture_that_lost_telegrams_keeps_its_velocity_per_interval(tmp_path: Path) -> None:
    """The building (world 1, 2,000 scans) as an LMS-200 capture whose line flipped bits
        (8e-5 of them): the importer skips the damaged telegrams (a fifth), and their times leave
        intervals of two to seven scans. The velocity is rescaled to each scan's interval before
        the scan's motion is filtered into it; mixing the intervals, this mapped 0.76 m off
    (`python -m bench.lost_telegrams`' capture)."""
    sim = simulate("building", seed=1, scans=2000)
    ds = captured(replace(sim, dataset=replace(sim.dataset, odometry=None)), 8e-5, tmp_path)
    assert 0.15 * sim.dataset.n_scans < ds.report.records_dropped < 0.3 * sim.dataset.n_scans
    intervals = np.diff(ds.t) / np.median(np.diff(ds.t))
    assert intervals.max() > 4
    truth = truth_poses(ds)
    assert truth is not None
    assert evaluate(slam_trajectory(ds)[0].poses, truth)["ate"]["rmse"] <= 0.3


def test_a_host_clock_that_jitters_is_read_at_the_scanners_rate(cli: Cli, tmp_path: Path) -> None:
    """The building (world 0, 4,000 scans) as an LMS-200 capture whose host stamped each scan
    late by a varying delay (sd 0.15 of the period, as the Mines URG logs' host): each
    interval read as it was stamped, the velocity was rescaled at every one beyond a quarter
    and mapped 0.48 m off (0.10 m with the scans' own times). On the scanner's slots: 0.07 m,
    and `toolkit map` says how it read the times."""
    sim = simulate("building", seed=0)
    ds = captured(replace(sim, dataset=replace(sim.dataset, odometry=None)), 0.0, tmp_path, 0.15)
    intervals = np.diff(ds.t) / np.median(np.diff(ds.t))
    assert np.mean(np.abs(np.log(intervals)) > np.log(1.25)) > 0.2
    toolkit.save(ds, tmp_path / "ds")
    code, out, err = cli("map", tmp_path / "ds", "--out", tmp_path / "run")
    assert code == 0, err
    assert re.search(
        r"scan times read as whole periods of 65 ms \(stamped 0\.[67]\d-1\.[34]\d", out
    )
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["scan_clock"]["lost"] == 0  # rounded from the stamp before: 32
    assert metrics["ate"]["rmse"] <= 0.2


def test_a_bag_whose_stamps_jitter_maps_as_one_stamped_evenly(tmp_path: Path) -> None:
    """The corridor (world 0, 2,000 scans) as a ROS bag without odometry whose LaserScan
    header stamps spread by 0.15 of the period (a driver that stamps each scan when the host
    reads it): on the scanner's slots it maps as the bag with even stamps does (0.15 m
    both); read as stamped, 0.79 m."""
    sim = simulate("corridor", seed=0, scans=2000)
    sim = replace(sim, dataset=replace(sim.dataset, odometry=None))
    ates = []
    for jitter in (0.0, 0.15):
        ds = captured(sim, 0.0, tmp_path / str(jitter), jitter, fmt="rosbag")
        truth = truth_poses(ds)
        assert truth is not None and ds.n_scans == sim.dataset.n_scans
        ates.append(evaluate(slam_trajectory(ds)[0].poses, truth)["ate"]["rmse"])
    even, jittered = ates
    assert jittered <= 0.3 and jittered <= even + 0.05


@pytest.mark.parametrize(("lost_share", "most_wrong"), [(0.0, 5), (0.2, 180)])
def test_slots_of_a_clock_that_jitters_by_a_third_of_a_period_and_wanders(
    lost_share: float, most_wrong: int
) -> None:
    """3,000 scans of 0.1 s stamped with jitter of a third of a period (sd) by a host clock
    whose offset wanders by 0.6 of a period and drifts by 0.6 over the log, with or without a
    fifth of the scans lost: the period within 0.3% (the wander leans it), the scans lost
    within 5 of the truth, few intervals read wrong (3 and 132). Each stamp rounded to its
    slot alone: the period 1.2% and 3.1% off, 85 scans read as lost where none was and 641
    where 714 were, 85 and 389 intervals wrong."""
    rng = np.random.default_rng(7)
    kept = np.flatnonzero(rng.random(4000) >= lost_share)[:3000]
    i = np.arange(3000)
    wander = 0.06 * np.sin(2 * np.pi * i / 1500) + 2e-5 * i
    t = np.maximum.accumulate(50 + 0.1 * kept + wander + rng.normal(0, 0.1 * 0.3, 3000))
    clock = scan_clock(t)
    assert abs(clock["period"] - 0.1) < 3e-4  # the wander leans the slope
    assert abs(clock["lost"] - (kept[-1] - kept[0] - 2999)) <= 5
    slots = np.rint((on_slots(t) - t[0]) / clock["period"])
    assert np.sum(np.diff(slots) != np.diff(kept)) <= most_wrong


def test_a_capture_whose_clock_jitters_by_a_third_of_a_period_maps(tmp_path: Path) -> None:
    """The corridor (world 2, 2,000 scans) as an LMS-200 capture whose host jitters by a
    third of a period: each stamp rounded to its slot alone, 92 scans read as lost and the
    period 3% short, mapped 0.56 m off; on the slots most likely as a whole, 0.13 m (0.10 with
    the scans' own times)."""
    sim = simulate("corridor", seed=2, scans=2000)
    ds = captured(replace(sim, dataset=replace(sim.dataset, odometry=None)), 0.0, tmp_path, 0.3)
    clock = scan_clock(ds.t)
    assert clock["lost"] <= 3
    truth = truth_poses(ds)
    assert truth is not None
    assert evaluate(slam_trajectory(ds)[0].poses, truth)["ate"]["rmse"] <= 0.25


def test_on_slots_reads_a_jittered_clock_as_whole_periods() -> None:
    """Stamps 0.1 s apart, each late by up to 35 ms, one scan lost: whole periods of about
    0.1 s, the lost scan's two; times that do not increase are returned as they are."""
    late = np.random.default_rng(0).uniform(0.0, 0.035, 50)
    t = 5.0 + 0.1 * np.delete(np.arange(51), 20) + late
    clock = scan_clock(t)
    assert abs(clock["period"] - 0.1) < 0.002 and clock["lost"] == 1 and jitters(clock)
    slots = on_slots(t)
    expected = np.where(np.arange(49) == 19, 2, 1)
    np.testing.assert_allclose(np.diff(slots) / clock["period"], expected, rtol=1e-9)
    assert slots[0] == t[0]
    np.testing.assert_array_equal(on_slots(np.full(4, 3.0)), np.full(4, 3.0))
    np.testing.assert_array_equal(on_slots(np.array([1.0])), [1.0])
    assert not jitters(scan_clock(np.arange(50) * 0.1)) and scan_clock(np.full(4, 3.0)) == {}


@pytest.mark.parametrize(("share", "within"), [(0.1, 0.3), (0.3, 0.5)])
def test_scans_dropped_at_random_keep_the_velocity_per_interval(
    share: float, within: float
) -> None:
    """The corridor (world 0, 2,000 scans; 0.14 m with every scan) with a tenth of its scans
    dropped at random: 1.28 m before the velocity went by each scan's interval. Three tenths:
    2.70 m, and still 1.38 m with the start velocity taken per the first interval (a scan
    lost there) instead of the log's usual one."""
    ds = replace(simulate("corridor", seed=0, scans=2000).dataset, odometry=None)
    kept = np.random.default_rng(0).random(ds.n_scans) >= share
    kept[0] = True
    log = replace(ds, t=ds.t[kept], ranges=ds.ranges[kept])
    truth = truth_poses(log)
    assert truth is not None
    assert evaluate(slam_trajectory(log)[0].poses, truth)["ate"]["rmse"] <= within


def test_the_velocity_keeps_its_speed_where_the_fit_does_not_observe_the_axis() -> None:
    # corridor seed 9 (development): over its first corridor stretch the fit keeps a forward
    # offset of its seed (response about 0), and without the probe the filtered velocity fell
    # to 0.51 of the robot's speed by scan 72 (0.74 on average over scans 10-150)
    ds, _, speed = _without_odometry(9)
    matcher = MotionMatcher(ds.laser, step=start_velocity(ds))
    response, velocity = [], []
    for k in range(300):
        matcher.push_predicted(ds.ranges[k], float(ds.t[k]))
        response.append(matcher.response)
        velocity.append(matcher._step[0])
    assert np.median(response[10:110]) < 0.2
    assert min(velocity) > 0.85 * speed


@pytest.mark.parametrize("scenario", ["corridor", "building"])
def test_start_velocity_is_the_robots_speed(scenario: str) -> None:
    # both start at full speed along a corridor: standstill matches about as well
    ds, _, speed = _without_odometry(17, scenario)
    step = start_velocity(ds)
    assert step is not None
    assert abs(step[0] - speed) < 0.1 * speed and abs(step[1]) < 0.1 * speed


def test_the_start_velocity_is_taken_where_the_fit_observes_forward_motion() -> None:
    # corridor seed 53 (spent held-out): the unfiltered first pass parked at "not moved" over
    # scans 90-270, so the plain median of its second half was 0.002 m a scan (truth 0.080)
    ds, _, speed = _without_odometry(53)
    step = start_velocity(ds)
    assert step is not None
    assert abs(step[0] - speed) < 0.05 * speed


def test_a_corridor_bare_for_its_first_pass_is_started_where_the_pass_sees_forward_motion(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # corridor world 192 (spent held-out, session 39): no scan of its first 300 observes the
    # forward motion (responses under 0.4), the pass random-walked to rest, its weighted
    # median was -0.003 m a scan (truth 0.080) and the log mapped 21.1 m off; the pass now
    # goes on until forward motion is observed (scans 350-550 here). On the scanner's slots
    # (session 49) its first 300 scans keep the speed; read as stamped (whole ms, the
    # prediction scaled by 0.5% steps) they park. Of worlds 180-214 only 192 parked, on main
    ds, truth, speed = _without_odometry(192)
    step = start_velocity(ds)
    assert step is not None
    assert abs(step[0] - speed) < 0.05 * speed
    result, _ = slam_trajectory(ds)
    assert evaluate(result.poses, truth)["ate"]["rmse"] <= 0.3
    monkeypatch.setattr(localmap, "START_STRONG", 0.0)  # the first 300 scans only
    slotted = start_velocity(ds)
    assert slotted is not None and abs(slotted[0] - speed) < 0.05 * speed
    monkeypatch.setattr(localmap, "on_slots", lambda t: np.asarray(t, np.float64))
    parked = start_velocity(ds)
    assert parked is not None and abs(parked[0]) < 0.2 * speed


def test_a_corridor_that_turns_bare_between_two_probes_keeps_the_speed_it_had() -> None:
    # building world 305 (spent held-out, session 40): out of a turn the robot enters a
    # corridor bare along its axis at scan 1711, between two probes; the response probed at
    # 1708 (0.97) was kept for fits 1709-1710 that no longer observed the forward motion
    # (0.054 and 0.057 m a scan against the truth's 0.039), the velocity ran 14% fast over
    # scans 1714-2100 and the log mapped 0.666 m off. Those forward motions now wait for the
    # next probe and are taken in at its response (0.32)
    ds, truth, _ = _without_odometry(305, "building")
    poses = sequential(ds).poses
    walked, truth_walked = (
        np.hypot(*np.diff(p[1714:2100, :2], axis=0).T).sum() for p in (poses, truth)
    )
    assert abs(walked / truth_walked - 1.0) < 0.04
    result, _ = slam_trajectory(ds)
    assert evaluate(result.poses, truth)["ate"]["rmse"] <= 0.3


def test_the_forward_velocity_holds_where_the_fit_observes_it_in_part() -> None:
    # corridor seed 48 (spent held-out), from the start velocity: with the forward gain
    # proportional to the response (not its square) the velocity sagged to 0.87 of the speed
    # over the partly observed stretches (response 0.05-0.2) and 1.93 m were lost in 700 scans
    ds, truth, speed = _without_odometry(48)
    matcher = MotionMatcher(ds.laser, step=start_velocity(ds))
    poses, velocity = [], []
    for k in range(700):
        poses.append(matcher.push_predicted(ds.ranges[k], float(ds.t[k])))
        velocity.append(matcher._step[0])
    walked = np.hypot(*np.diff(np.array(poses)[:, :2], axis=0).T).sum()
    truth_walked = np.hypot(*np.diff(truth[:700, :2], axis=0).T).sum()
    assert min(velocity) > 0.93 * speed
    assert truth_walked - walked < 1.0


def test_weighted_median() -> None:
    values = np.array([3.0, 0.0, 2.0, 1.0])
    assert weighted_median(values, np.array([0.0, 0.0, 1.0, 0.0])) == 2.0
    assert weighted_median(values, np.ones(4)) == 1.0  # the lower middle one
    assert weighted_median(values, np.array([1.0, 0.1, 0.1, 0.1])) == 3.0


def _standing_first(ds: toolkit.Dataset, scans: int) -> toolkit.Dataset:
    """`ds` with `scans` scans of the robot standing at its first pose put before it: scan 0
    again with fresh range noise (1 cm, the simulator's), the truth still."""
    truth = truth_poses(ds)
    assert truth is not None
    dt = float(ds.t[1] - ds.t[0])
    t = np.concatenate([ds.t[0] - dt * np.arange(scans, 0, -1), ds.t])
    rng = np.random.default_rng(1)
    still = ds.ranges[:1] + rng.normal(0.0, 0.01, (scans, ds.n_beams)).astype(np.float32)
    poses = np.concatenate([np.repeat(truth[:1], scans, axis=0), truth])
    frame = pd.DataFrame({"t": t, "x": poses[:, 0], "y": poses[:, 1], "theta": poses[:, 2]})
    ranges = np.concatenate([still, ds.ranges]).astype(np.float32)
    return replace(ds, t=t, ranges=ranges, odometry=None, groundtruth=frame)


def test_a_log_that_starts_at_rest_keeps_still_then_takes_the_velocity() -> None:
    # 14.7 m when the start velocity was applied from scan 0 (a mutation run)
    ds = _standing_first(simulate("corridor", seed=21).dataset, 150)
    assert standing(ds.ranges) in range(150, 153)  # the first moving scans change little
    assert standing(simulate("corridor", seed=21).dataset.ranges) == 1
    result, _ = slam_trajectory(ds)
    truth = truth_poses(ds)
    assert truth is not None
    assert evaluate(result.poses, truth)["ate"]["rmse"] <= 0.5


def test_a_swaying_scanner_keeps_its_path_with_the_probe_along_the_motion() -> None:
    # a hand-held scanner swept +-0.3 rad every 2 s (peak 0.94 rad/s) along the building
    # (development seed 2): probed along the heading, the unobserved along-corridor part of
    # its sideways motion is filtered at full gain and the trajectory strays (4.04 m ATE);
    # probed along the predicted motion, 1.30 m (session 26, handheld26)
    sim = simulate("building", seed=2, sway=0.3, sway_period=2)
    ds = replace(sim.dataset, odometry=None)
    truth = truth_poses(ds)
    assert truth is not None
    ate = {
        axis: float(
            evaluate(sequential(ds, MatchConfig(probe_axis=axis)).poses, truth)["ate"]["rmse"]
        )
        for axis in ("heading", "motion")
    }
    assert ate["motion"] < 0.5 * ate["heading"]
    assert ate["motion"] < 2.0


def _sideways(poses: np.ndarray, scans: slice) -> float:
    """The robot's motion to its left, summed over the steps into `scans` (robot frame)."""
    steps = se2.between(poses[:-1], poses[1:])
    return float(steps[scans.start - 1 : scans.stop - 1, 1].sum())


def test_a_narrow_view_turns_on_the_spot_without_sliding_sideways() -> None:
    """The corridor (development world 3) in the LMS-200's 100-degree mode at 0.5 degrees a
    beam, without odometry: at a corner the robot stops and turns on the spot, 0.1 rad a scan,
    and the velocity's turn lags the robot's. Fitted from a seed without the turn, the walls
    ahead took a turn about a point 1.5 m in front of the robot (as well fitted as the truth's
    turn, or better) and the velocity learnt the slide: 1.08 m sideways through the corner. A
    vehicle's fit that slides is fitted again from the fitted turn without the slide: 0.02 m."""
    sim = simulate("corridor", seed=3, scans=2000, fov_deg=100, beams=201)
    truth = truth_poses(sim.dataset)
    assert truth is not None
    corner = slice(988, 1012)
    assert abs(float(truth[corner.stop, 2] - truth[corner.start, 2])) > 1.5  # the turn
    assert abs(_sideways(truth, corner)) < 0.01
    poses = sequential(replace(sim.dataset, odometry=None)).poses
    assert abs(_sideways(poses, corner)) < 0.1


def test_a_capture_in_the_lms200s_100_degree_mode_maps(tmp_path: Path) -> None:
    """The corridor (development world 6) as a raw LMS-200 capture in its 100-degree mode at
    0.5 degrees a beam (201 beams), without odometry: 0.61 m before a fit's slide sideways
    was checked, 0.25 m after (`python -m bench.narrow_view`)."""
    sim = simulate("corridor", seed=6, scans=2000, fov_deg=100, beams=201)
    ds = captured(replace(sim, dataset=replace(sim.dataset, odometry=None)), 0.0, tmp_path)
    assert ds.laser.beams == 201
    assert np.degrees(ds.laser.angle_increment * (ds.laser.beams - 1)) == pytest.approx(100)
    truth = truth_poses(ds)
    assert truth is not None
    assert evaluate(slam_trajectory(ds)[0].poses, truth)["ate"]["rmse"] <= 0.4
