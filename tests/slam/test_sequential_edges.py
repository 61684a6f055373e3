"""The sequential edges' covariances: the floor model by default, and with
`SlamConfig.matcher_cov` the front end's own per-step covariances, turned into each step's
first scan frame, summed over the edge, scaled and floored."""

from __future__ import annotations

import numpy as np

import toolkit
from toolkit import se2
from toolkit.metrics import evaluate
from toolkit.poses import truth_poses, with_drift
from toolkit.slam.pipeline import SlamConfig, local_map_edges, odometry_edges, sequential_edges
from toolkit.slam.run import slam_trajectory
from toolkit.slam.scanmap import scan_to_map


def _steps(n: int, rng: np.random.Generator) -> np.ndarray:
    """n random symmetric positive definite 3 x 3 step covariances (world frame)."""
    a = rng.normal(size=(n, 3, 3)) * np.array([0.01, 0.01, 0.002])[:, None]
    return np.asarray(a @ a.transpose(0, 2, 1) + np.eye(3) * 1e-6)


def test_default_is_the_floor_model_whatever_the_step_covariances() -> None:
    rng = np.random.default_rng(0)
    poses = np.c_[np.arange(6) * 0.5, np.zeros(6), np.linspace(0, 1, 6)]
    keys = np.array([0, 2, 3, 5])
    config = SlamConfig()
    plain = sequential_edges(keys, poses, config)
    given = sequential_edges(keys, poses, config, _steps(5, rng))
    for a, b in zip(plain, given, strict=True):
        assert np.array_equal(a.covariance, b.covariance)
    length = np.hypot(plain[0].pose[0], plain[0].pose[1]) + 0.3 * abs(plain[0].pose[2])
    assert np.isclose(plain[0].covariance[0, 0], (0.02 + 0.02 * length) ** 2)


def test_matcher_covariances_turned_into_the_scan_frame_and_summed_over_the_edge() -> None:
    rng = np.random.default_rng(1)
    poses = np.c_[np.arange(6) * 0.5, np.ones(6), np.array([0.3, 1.2, -2.0, 0.4, 2.5, 0.0])]
    keys = np.array([0, 1, 3, 5])  # one step, then two, then two
    steps = _steps(5, rng)
    config = SlamConfig(matcher_cov=3.0, matcher_floor=(0.01, 0.0025))
    edges = sequential_edges(keys, poses, config, steps)

    def turned(k: int) -> np.ndarray:
        c, s = np.cos(poses[k, 2]), np.sin(poses[k, 2])
        rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        return np.asarray(rot @ steps[k] @ rot.T)

    floor = np.diag([0.01**2, 0.01**2, 0.0025**2])
    assert np.allclose(edges[0].covariance, 9.0 * turned(0) + floor)
    assert np.allclose(edges[1].covariance, 9.0 * (turned(1) + turned(2)) + floor)
    assert np.allclose(edges[2].covariance, 9.0 * (turned(3) + turned(4)) + floor)
    # not the world-frame covariance: the heading of scan 1 (1.2 rad) turns it
    assert not np.allclose(edges[1].covariance, 9.0 * (steps[1] + steps[2]) + floor)
    # the relative poses are the floor model's
    plain = sequential_edges(keys, poses, SlamConfig())
    for a, b in zip(plain, edges, strict=True):
        assert np.array_equal(a.pose, b.pose) and (a.a, a.b) == (b.a, b.b)


def test_the_mapper_passes_the_front_ends_covariances_when_asked(building: toolkit.Dataset) -> None:
    """`slam_trajectory` hands the scan-to-map front end's step covariances to the graph: with
    `matcher_cov` the sequential edges are no longer the floor model's, the map stays right."""
    truth = truth_poses(building)
    assert truth is not None
    ds = with_drift(building, seed=0)
    result, run = slam_trajectory(ds, slam=SlamConfig(matcher_cov=3.0))
    _, plain = slam_trajectory(ds)
    # the sequential edges come first (then the odometry's where no loop reaches, the loops)
    seq = run.edges[: len(run.keys) - 1]
    seq_plain = plain.edges[: len(plain.keys) - 1]
    assert len(seq) == len(seq_plain) > 100 and not any(e.loop for e in seq)
    floor = sequential_edges(run.keys, run.before, SlamConfig())
    changed = [not np.allclose(e.covariance, f.covariance) for e, f in zip(seq, floor, strict=True)]
    assert np.mean(changed) > 0.9
    # ... they are the front end's own, as `sequential_edges` builds them from its matches
    front = scan_to_map(ds)
    assert front.matches is not None
    own = sequential_edges(
        run.keys, run.before, SlamConfig(matcher_cov=3.0), front.matches.covariance
    )
    for e, o in zip(seq, own, strict=True):
        assert np.allclose(e.covariance, o.covariance)
    assert evaluate(result.poses, truth)["ate"]["rmse"] < 0.1


def test_lag_edges_join_the_scan_to_map_front_end_only_when_asked(
    building: toolkit.Dataset,
) -> None:
    """`SlamConfig.lag_edges`: the scan-to-map front end's graph gets no local-map edges by
    default; with the setting each keyframe is tied to the 2nd .. 4th keyframe before it, by
    edges that measure the truth's relative poses, and the mapper puts them in its graph."""
    truth = truth_poses(building)
    assert truth is not None
    ds = with_drift(building, seed=0)
    _, plain = slam_trajectory(ds)
    keys, before = plain.keys, plain.before
    assert local_map_edges(ds, keys, before, SlamConfig()) == []
    lagged = local_map_edges(ds, keys, before, SlamConfig(lag_edges=True))
    lags = np.searchsorted(keys, [e.b for e in lagged]) - np.searchsorted(
        keys, [e.a for e in lagged]
    )
    assert set(lags.tolist()) == {2, 3, 4} and len(lagged) > 2 * len(keys)
    off = [np.hypot(*(e.pose[:2] - se2.between(truth[e.a], truth[e.b])[:2])) for e in lagged]
    assert np.median(off) < 0.03 and np.max(off) < 0.2
    result, run = slam_trajectory(ds, slam=SlamConfig(lag_edges=True))
    assert len(run.edges) >= len(plain.edges) + len(lagged) // 2
    assert evaluate(result.poses, truth)["ate"]["rmse"] < 0.1


def test_odometry_edges_take_the_scale_out_and_hold_only_the_forward_motion() -> None:
    """`SlamConfig.odometry_along`: per keyframe pair the odometry's motion with its scale
    (the odometry's path over the estimate's) divided out, tight along the first keyframe's
    heading only; off (0), no edge."""
    rng = np.random.default_rng(2)
    steps = np.c_[rng.uniform(0.5, 1.0, 8), rng.normal(0, 0.05, 8), rng.normal(0, 0.2, 8)]
    before = np.zeros((9, 3))
    odometry = np.zeros((9, 3))
    for k, step in enumerate(steps):
        before[k + 1] = se2.compose(before[k], step)
        odometry[k + 1] = se2.compose(odometry[k], step * np.array([1.03, 1.03, 1.0]))
    keys = np.array([0, 1, 2, 4, 5, 8])
    assert odometry_edges(keys, before, odometry, SlamConfig(odometry_along=0.0)) == []
    config = SlamConfig(odometry_along=0.02, odometry_per_metre=0.01, odometry_loose=(0.5, 0.3))
    edges = odometry_edges(keys, before, odometry, config)
    truth = se2.between(before[keys[:-1]], before[keys[1:]])
    for e, t, a, b in zip(edges, truth, keys[:-1], keys[1:], strict=True):
        assert (e.a, e.b) == (a, b) and not e.loop
        assert np.allclose(e.pose, t, atol=1e-9)  # the 3% scale is out
        along = 0.02 + 0.01 * np.hypot(t[0], t[1])
        assert np.allclose(e.covariance, np.diag([along**2, 0.25, 0.09]))
    # the odometry's scale as it is: the edges are 3% longer than the estimate's
    raw = se2.between(odometry[keys[:-1]], odometry[keys[1:]])
    assert np.allclose(np.hypot(raw[:, 0], raw[:, 1]), 1.03 * np.hypot(truth[:, 0], truth[:, 1]))


def test_the_mapper_adds_odometry_edges_only_where_asked(building: toolkit.Dataset) -> None:
    """Off, no odometry edge; `odometry_along` with no reach: one odometry edge per
    sequential edge; with `odometry_reach` (the default's 10 m, here 3 m), only on edges
    farther along the path than that from every accepted loop's end; the map stays right."""
    truth = truth_poses(building)
    assert truth is not None
    ds = with_drift(building, seed=0)
    _, plain = slam_trajectory(ds, slam=SlamConfig(odometry_along=0.0))
    seq = sum(not e.loop for e in plain.edges)
    _, every = slam_trajectory(ds, slam=SlamConfig(odometry_along=0.02, odometry_reach=0.0))
    assert sum(not e.loop for e in every.edges) == 2 * seq
    assert SlamConfig().odometry_along > 0 and SlamConfig().odometry_reach > 0
    result, reach = slam_trajectory(ds, slam=SlamConfig(odometry_along=0.02, odometry_reach=3.0))
    added = [e for e in reach.edges if not e.loop][seq:]
    ends = np.array([along for lp in reach.loops if lp.accepted for along in (lp.a, lp.b)])
    assert 0 < len(added) < seq and len(ends) > 0
    path = np.r_[0, np.cumsum(np.hypot(*np.diff(reach.before[:, :2], axis=0).T))]
    mid = 0.5 * (path[[e.a for e in added]] + path[[e.b for e in added]])
    assert np.abs(mid[:, None] - path[ends][None, :]).min(axis=1).min() > 3.0
    assert evaluate(result.poses, truth)["ate"]["rmse"] < 0.1
