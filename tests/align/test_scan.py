"""The whole-log scan matcher on simulated scans with known truth: accuracy from perturbed
odometry, corridor degeneracy, slip rescue, covariance, streaming equal to batch."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit import se2
from toolkit.align import scan as sc
from toolkit.poses import odometry_poses, truth_poses
from toolkit.sim import LaserModel, simulate
from toolkit.sim.geometry import WorldBuilder


@pytest.fixture(scope="module")
def building() -> object:
    return simulate("building", seed=3, scans=400).dataset


def perturbed_seeds(truth_steps: np.ndarray, laser: object, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = np.column_stack(
        [
            rng.uniform(-0.06, 0.06, (len(truth_steps), 2)),
            rng.uniform(-0.05, 0.05, len(truth_steps)),
        ]
    )
    return se2.laser_motion(truth_steps, laser) + noise  # type: ignore[arg-type]


def test_recovers_true_motion_from_odometry_off_by_6cm_and_3deg(building: object) -> None:
    ds = building
    truth = truth_poses(ds)  # type: ignore[arg-type]
    steps = se2.between(truth[:-1], truth[1:])
    seeds = perturbed_seeds(steps, ds.laser, seed=1)  # type: ignore[attr-defined]
    m = sc.match_pairs(ds.ranges, seeds, ds.laser)  # type: ignore[attr-defined]
    est = se2.robot_motion(m.pose, ds.laser)  # type: ignore[attr-defined]
    err = se2.between(steps, est)
    et, er = np.hypot(err[:, 0], err[:, 1]), np.abs(err[:, 2])
    seed_err = np.hypot(*(seeds - se2.laser_motion(steps, ds.laser))[:, :2].T)  # type: ignore[attr-defined]
    assert np.median(seed_err) > 0.03
    # where the scans fix both directions the estimate is within a centimetre; in corridors
    # (degenerate) the motion along the corridor stays the odometry's, by design
    full = m.degenerate == 0
    assert full.mean() > 0.5
    assert np.median(et[full]) < 0.01 and np.percentile(et[full], 90) < 0.04
    assert np.median(er) < np.deg2rad(0.2) and np.percentile(er, 95) < np.deg2rad(1.0)
    assert (m.covariance[:, [0, 1, 2], [0, 1, 2]] > 0).all()
    assert (m.sigma < 0.05).mean() > 0.95


def featureless_corridor() -> tuple[object, np.ndarray, np.ndarray]:
    """Two parallel walls 3 m apart, 400 m long: nothing fixes the motion along them."""
    world = WorldBuilder()
    world.segment((-200.0, -1.5), (200.0, -1.5))
    world.segment((-200.0, 1.5), (200.0, 1.5))
    model = LaserModel(units="mm", mixed_prob=0.0)
    truth = np.array([[0.0, 0.2, 0.0], [0.3, 0.1, 0.05]])
    ranges = model.measure(world.build(), truth, np.random.default_rng(0))
    return model.geometry(), ranges, truth


def test_corridor_keeps_odometry_along_the_unobservable_direction() -> None:
    laser, ranges, truth = featureless_corridor()
    step = se2.laser_motion(se2.between(truth[:1], truth[1:]), laser)[0]
    seed = step + np.array([0.25, -0.08, 0.04])  # odometry: 25 cm too far, 8 cm aside, 2.3°
    m = sc.match_pairs(ranges, seed[None], laser)
    p = m.pose[0]
    assert m.degenerate[0] == 1
    assert abs(p[2] - step[2]) < np.deg2rad(0.2)  # rotation: fixed by the walls
    # across the corridor (the previous laser's y) the scans correct odometry; along it (x)
    # nothing is invented
    lateral, along = np.array([0.0, 1.0]), np.array([1.0, 0.0])
    assert abs((p[:2] - step[:2]) @ lateral) < 0.01
    assert abs((p[:2] - seed[:2]) @ along) < 0.02
    # and the covariance says so: odometry's variance along the corridor, mm across
    cov = m.covariance[0, :2, :2]
    assert along @ cov @ along > 100 * (lateral @ cov @ lateral)


def test_a_wheel_slip_of_34_degrees_is_rescued(building: object) -> None:
    ds = building
    truth = truth_poses(ds)  # type: ignore[arg-type]
    steps = se2.laser_motion(se2.between(truth[:-1], truth[1:]), ds.laser)[::40]  # type: ignore[attr-defined]
    seeds = steps + np.array([0.0, 0.0, 0.6])
    ranges = ds.ranges  # type: ignore[attr-defined]
    idx = np.arange(0, len(truth) - 1, 40)
    pairs = np.stack([ranges[idx], ranges[idx + 1]], axis=1).reshape(-1, ranges.shape[1])
    ref = np.arange(len(pairs)) - 1
    ref[0::2] = 0
    ref[1::2] = np.arange(0, len(pairs), 2)
    # pair k: scan 2k+1 against 2k; odd-to-even steps get a harmless seed of "no motion"
    all_seeds = np.zeros((len(pairs) - 1, 3))
    all_seeds[0::2] = seeds
    ref[0::2] = np.maximum(np.arange(0, len(pairs), 2) - 1, 0)
    m = sc.match_pairs(pairs, all_seeds, ds.laser, ref=ref)  # type: ignore[attr-defined]
    err = np.abs(se2.wrap(m.pose[0::2, 2] - steps[:, 2]))
    assert np.median(err) < np.deg2rad(0.5) and err.max() < np.deg2rad(2.0)
    for config, least in (
        (sc.MatchConfig(rescue_step=0, restart_turn=-1), 3),  # no ladder, no restart
        (sc.MatchConfig(rescue_step=0), 1),  # a restart from the estimate alone
    ):
        off = sc.match_pairs(pairs, all_seeds, ds.laser, config, ref=ref)  # type: ignore[attr-defined]
        stuck = np.abs(se2.wrap(off.pose[0::2, 2] - steps[:, 2])) > np.deg2rad(10)
        assert stuck.sum() >= least  # without the ladder, pairs stay stuck


def test_paper_variant_and_bad_arguments(building: object) -> None:
    ds = building
    odo = odometry_poses(ds)  # type: ignore[arg-type]
    seeds = se2.laser_motion(se2.between(odo[:-1], odo[1:]), ds.laser)  # type: ignore[attr-defined]
    paper = sc.match_pairs(ds.ranges, seeds, ds.laser, sc.MatchConfig(variant="paper"))  # type: ignore[attr-defined]
    text = sc.match_pairs(ds.ranges, seeds, ds.laser)  # type: ignore[attr-defined]
    assert not np.allclose(paper.pose, text.pose)
    with pytest.raises(ValueError, match="seeds"):
        sc.match_pairs(ds.ranges, seeds[:-1], ds.laser)  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="earlier scan"):
        sc.match_pairs(ds.ranges, seeds, ds.laser, ref=np.arange(len(seeds) + 1))  # type: ignore[attr-defined]


def test_streaming_gives_the_batch_poses_in_constant_memory(building: object) -> None:
    from toolkit.poses import build

    ds = building
    batch = build(ds, "gaussian").poses  # type: ignore[arg-type]
    odo = odometry_poses(ds)  # type: ignore[arg-type]
    stream = sc.StreamMatcher(ds.laser)  # type: ignore[attr-defined]
    held = stream.working_bytes
    poses = np.array([stream.push(r, o) for r, o in zip(ds.ranges, odo, strict=True)])  # type: ignore[attr-defined]
    assert stream.working_bytes == held < 40 * ds.n_beams + 512  # type: ignore[attr-defined]
    assert np.abs(poses - batch).max() < 1e-9
    with pytest.raises(ValueError, match="beams"):
        stream.push(np.zeros(3), odo[0])


def test_keyframes_follow_odometry() -> None:
    odo = np.column_stack([np.arange(10) * 0.1, np.zeros(10), np.zeros(10)])
    assert list(sc.keyframes(odo, 0.25, 1.0)) == [0, 0, 0, 0, 3, 3, 3, 6, 6, 6]
    assert list(sc.keyframes(odo, 0.0, 0.0)) == [0, 0, 1, 2, 3, 4, 5, 6, 7, 8]


def test_kernel_parameters_fill_every_named_slot() -> None:
    laser = LaserModel().geometry()
    config = sc.MatchConfig(variant="paper", odometry_sigma=(0.07, 0.03), restart_turn=-1.0)
    params = sc._params(config, laser)
    assert params.shape == (sc._PARAMS,) and np.isfinite(params).all()
    assert params[sc._P_PAPER] == 1.0 and params[sc._P_RESTART_TURN] == -1.0
    assert params[sc._P_ODOMETRY_SIGMA_T] == 0.07 and params[sc._P_ODOMETRY_SIGMA_R] == 0.03
    assert params[sc._P_BEAM_STEP] == abs(laser.angle_increment)
