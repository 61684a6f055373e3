"""`SlamConfig.blind_turn`: the sequential edges across steps the front end could not verify
(a scan too sparse to search whose fit failed) loosened in heading, so that the loops take a
slip of the odometry out there."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from tests.slam.conftest import drifted_carmen
from toolkit import se2
from toolkit.metrics import evaluate
from toolkit.poses import odometry_poses, truth_poses
from toolkit.slam.pipeline import (
    SlamConfig,
    blind_steps,
    loosen_blind,
    mend_blind,
    sequential_edges,
)
from toolkit.slam.run import slam_trajectory
from toolkit.slam.scanmap import SEARCH_MIN, MapConfig, returns, scan_to_map


def test_only_edges_across_an_unverified_sparse_step_are_loosened() -> None:
    """A step is blind when its scan has fewer than 20 returns within `max_range` and its fit
    put fewer than `min_inliers` of them near the map; only the keyframe edges spanning one
    change: `blind_turn` squared more in heading, (length x blind_turn) squared across."""
    ranges = np.full((7, 40), 5.0, dtype=np.float32)
    ranges[2, 15:] = np.inf  # 15 returns, fit failed: blind
    ranges[3, 15:] = 30.0  # 15 within max_range (25 m), fit good: verified
    ranges[5, 10:] = 0.0  # 10 returns, fit failed: blind
    fit = np.array([0.9, 0.2, 0.9, 0.9, 0.1, 0.9])  # pair k = scan k -> k + 1
    config = SlamConfig(blind_turn=0.7, blind_min_turn=0.0)
    poses = np.c_[np.arange(7) * 0.4, np.zeros(7), [0.0, 0.1, -0.2, -0.1, 0.0, 0.05, 0.1]]
    blind = blind_steps(ranges, fit, poses, config)
    assert blind.tolist() == [False, True, False, False, True, False]
    # with `blind_min_turn`, only those that turn more (1 -> 2 turns 0.3 rad, 4 -> 5 0.05)
    gated = blind_steps(ranges, fit, poses, replace(config, blind_min_turn=0.2))
    assert gated.tolist() == [False, True, False, False, False, False]
    keys = np.array([0, 1, 3, 4, 6])
    plain = sequential_edges(keys, poses, config)
    loose = loosen_blind(plain, keys, blind, config)
    changed = [
        not np.array_equal(a.covariance, b.covariance) for a, b in zip(plain, loose, strict=True)
    ]
    assert changed == [False, True, False, True]  # 1 -> 3 holds step 1 -> 2, 4 -> 6 step 4 -> 5
    e, f = plain[1], loose[1]
    t = np.hypot(e.pose[0], e.pose[1]) * 0.7
    assert np.allclose(f.covariance - e.covariance, np.diag([t * t, t * t, 0.49]))
    assert all(
        np.array_equal(a.pose, b.pose) and (a.a, a.b) == (b.a, b.b)
        for a, b in zip(plain, loose, strict=True)
    )
    assert (
        loosen_blind(plain, keys, blind, replace(config, blind_turn=0.0)) is plain
    )  # off: the same edges


def test_a_slip_in_a_blind_stretch_is_taken_out_by_the_loops(real: Path) -> None:
    """freiburg-campus drift seed 45: at scan 925 (17 returns, in a stretch of 8 scans with
    8-17) the odometry slips 40 degrees; no scan there can be matched or searched, so the
    front end keeps the turn, and the graph spreads it over scans 800-1100 (1.7 m ATE). With
    the edge across it loose in heading the loops put the turn there (0.34 m)."""
    ds = drifted_carmen(real, "freiburg-campus", seed=45)
    truth = truth_poses(ds)
    assert truth is not None
    plain, _ = slam_trajectory(ds, slam=replace(SlamConfig(), blind_turn=0.0))
    loose, run = slam_trajectory(ds, slam=replace(SlamConfig(), blind_turn=1.5, blind_min_turn=0.2))
    before = evaluate(plain.poses, truth)["ate"]["rmse"]
    after = evaluate(loose.poses, truth)["ate"]["rmse"]
    assert before > 1.2 and after < 0.5
    assert run.metrics(ds)["false_loops"] == 0


def test_a_blind_stretch_is_rederived_from_its_fitted_ends() -> None:
    """`mend_blind`: the odometry slips 0.5 rad on the step into a blind scan (3) and the next
    fitted scan (4) takes the slip out; the blind scan's pose is re-derived from the two ends,
    the slip put on the step it leaves turning least. Scans outside the stretch keep their
    poses; a gate above the disagreement, or no blind scan, returns the same array."""
    truth = np.c_[np.arange(7) * 0.5, np.zeros(7), np.zeros(7)]
    truth[:, 2] = [0.0, 0.05, 0.1, 0.12, 0.1, 0.1, 0.08]
    steps = se2.between(truth[:-1], truth[1:])
    steps[2, 2] += 0.5  # the slip, on the step into scan 3
    odometry = np.vstack([truth[:1], np.zeros((6, 3))])
    for k in range(6):
        odometry[k + 1] = se2.compose(odometry[k], steps[k])
    before = truth.copy()
    before[3] = se2.compose(truth[2], steps[2])  # the front end kept the odometry's step
    ranges = np.full((7, 40), 5.0)
    ranges[3, 12:] = np.inf  # 12 returns: too few to search
    fit = np.array([0.9, 0.9, 0.1, 0.9, 0.9, 0.9])
    mended = mend_blind(ranges, fit, before, odometry, SlamConfig(blind_mend=0.25))
    assert abs(before[3, 2] - truth[3, 2]) > 0.45
    assert np.allclose(mended[3], truth[3], atol=1e-9)
    keep = np.arange(7) != 3
    assert np.array_equal(mended[keep], before[keep])
    assert mend_blind(ranges, fit, before, odometry, SlamConfig(blind_mend=0.6)) is before
    assert mend_blind(ranges, fit, before, odometry, SlamConfig()) is before  # off
    full = np.full((7, 40), 5.0)
    assert mend_blind(full, fit, before, odometry, SlamConfig(blind_mend=0.25)) is before


def test_a_slip_on_a_blind_scan_is_mended_and_nothing_else_moves(real: Path) -> None:
    """freiburg-campus drift seed 4: the odometry slips 20 degrees into scan 1014 (blind), the
    next scan's fit takes it out; the front end's scan 1014 is 18 degrees off the truth's step
    from 1013, mended < 1 degree; every other scan's pose before the loops is unchanged."""
    ds = drifted_carmen(real, "freiburg-campus", seed=4)
    truth, odometry = truth_poses(ds), odometry_poses(ds)
    assert truth is not None and odometry is not None
    front = scan_to_map(ds)
    assert front.matches is not None
    before = front.poses
    mended = mend_blind(
        ds.ranges, front.matches.agreement, before, odometry, SlamConfig(blind_mend=0.25)
    )

    def off(p: np.ndarray) -> float:
        rel, true = se2.between(p[1013], p[1014]), se2.between(truth[1013], truth[1014])
        return float(np.degrees(abs(se2.wrap(rel[2] - true[2]))))

    assert off(before) > 15 and off(mended) < 1
    moved = np.flatnonzero(np.any(mended != before, axis=1))
    assert moved.tolist() == [1014]


def test_a_small_slip_in_a_blind_stretch_stays_local_and_the_loops_keep_it(real: Path) -> None:
    """freiburg-campus drift seed 13, scans 928-930 (8-12 returns, fit failed): the front end
    keeps the odometry's steps there, 2-4 degrees more turning than the truth's, so scan 930
    stands 8 degrees turned against scan 927; the first fitted scan after them (931, 34
    returns) turns it back, so the chain is right (931 against 927 within 1 degree and 0.15 m).
    The default mapper's loops keep the turned scans as they are (within 0.2 degree of the
    front end's): the slip is a local defect that the ATE hardly sees (session 32, fc32).
    Read as the laser's poses (the default since session 34) scan 930 ends 0.1 degree off
    against 927, not turned: the test keeps PARAM's reading (`equal_poses="robot"`; session 34, carry34)."""
    ds = drifted_carmen(real, "freiburg-campus", seed=13, equal_poses="robot")
    truth = truth_poses(ds)
    odometry = odometry_poses(ds)
    assert truth is not None and odometry is not None
    result, run = slam_trajectory(ds)
    final = result.poses
    assert np.all(returns(ds.ranges[928:931], MapConfig().max_range) < SEARCH_MIN)

    def against(poses: np.ndarray, k: int) -> np.ndarray:
        """Scan k relative to scan 927, off the truth's (x, y, heading)."""
        return se2.between(se2.between(truth[927], truth[k]), se2.between(poses[927], poses[k]))

    assert abs(np.degrees(against(final, 930)[2])) > 5.0  # the blind scans turned
    chain = against(final, 931)
    assert abs(np.degrees(chain[2])) < 1.0 and float(np.hypot(chain[0], chain[1])) < 0.15
    # the blind steps are the odometry's (928 -> 930) in the estimate before loops and after
    odo_turn = se2.between(odometry[928], odometry[930])[2]
    for poses in (run.before, final):
        turn = se2.between(poses[928], poses[930])[2]
        assert abs(np.degrees(turn - odo_turn)) < 0.2
