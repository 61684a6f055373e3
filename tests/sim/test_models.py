"""Simulator models: ray-cast geometry, laser noise, odometry drift, labels, determinism."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from toolkit.errors import ToolkitError
from toolkit.sim import LaserModel, OdometryModel, Simulation, simulate
from toolkit.sim.geometry import GLASS, WorldBuilder, cast
from toolkit.sim.scenarios import sample_path
from toolkit.sim.truth import runs, training_regions

NOISELESS: dict[str, Any] = dict(range_sigma=0.0, mixed_prob=0.0, glass_return_prob=0.0)


def _box_corridor(width: float = 2.0, length: float = 20.0) -> WorldBuilder:
    """A straight corridor y in [-w/2, w/2], x in [0, length], closed at both ends."""
    b = WorldBuilder()
    h = width / 2
    b.polyline([(0.0, -h), (length, -h), (length, h), (0.0, h), (0.0, -h)])
    return b


def test_scan_in_known_corridor_gives_known_wall_distances() -> None:
    world = _box_corridor(width=2.0, length=20.0).build()
    laser = LaserModel(mount_x=0.0, units="mm", **NOISELESS)  # 8 m max range, 1 mm
    pose = np.array([[5.0, 0.25, 0.0]])  # facing +x, 0.75 m from the left wall
    r = laser.measure(world, pose, np.random.default_rng(0))[0]
    angles = laser.geometry().angles
    right, left, ahead = r[0], r[180], r[90]  # beam 0 = -90° (right), 90 = ahead, 180 = left
    assert right == pytest.approx(1.25, abs=1e-3)
    assert left == pytest.approx(0.75, abs=1e-3)
    assert np.isnan(ahead)  # the end wall is 15 m away: beyond the 8 m mode
    # every beam that reaches a side wall reads the perpendicular distance / |sin(angle)|
    with np.errstate(divide="ignore"):
        side = np.where(np.sin(angles) < 0, 1.25, 0.75) / np.abs(np.sin(angles))
    ok = side < 8.0 - 0.01
    np.testing.assert_allclose(r[ok], side[ok], atol=1e-3)
    assert np.isnan(r[side > 8.0 + 0.01]).all()


def test_cast_handles_circles_and_chunks() -> None:
    b = _box_corridor(width=4.0, length=30.0)
    b.circle(10.0, 0.0, 0.5)
    world = b.build()
    origins = np.column_stack([np.linspace(1.0, 8.0, 50), np.zeros(50)])
    headings = np.zeros(50)
    angles = np.array([0.0])
    small = cast(world, origins, headings, angles, 80.0, chunk_elements=16)
    big = cast(world, origins, headings, angles, 80.0)
    np.testing.assert_allclose(small.opaque[:, 0], 9.5 - origins[:, 0], atol=1e-4)
    np.testing.assert_allclose(small.opaque, big.opaque, atol=1e-5)  # float32 rounding


def test_glass_returns_only_near_normal_incidence() -> None:
    b = WorldBuilder()
    b.segment((-50.0, 2.0), (50.0, 2.0), GLASS)  # a long window 2 m to the left
    b.segment((-50.0, 6.0), (50.0, 6.0))  # a wall behind it
    world = b.build()
    laser = LaserModel(
        mount_x=0.0, range_sigma=0.0, glass_sigma=0.0, mixed_prob=0.0, glass_return_prob=1.0
    )
    r = laser.measure(world, np.zeros((1, 3)), np.random.default_rng(0))[0]
    incidence = np.abs(np.rad2deg(laser.geometry().angles) - 90.0)  # from the window's normal
    near = (incidence < laser.glass_normal_deg - 0.5) & (incidence < 90)
    far = (incidence > laser.glass_normal_deg + 0.5) & (incidence < 80)
    np.testing.assert_allclose(r[near], 2.0 / np.cos(np.deg2rad(incidence[near])), atol=0.006)
    np.testing.assert_allclose(r[far], 6.0 / np.cos(np.deg2rad(incidence[far])), atol=0.006)


def test_range_noise_has_the_modelled_spread() -> None:
    world = _box_corridor().build()
    laser = LaserModel(mount_x=0.0, units="mm", range_sigma=0.02, mixed_prob=0.0)
    poses = np.tile([5.0, 0.0, 0.0], (400, 1))
    r = laser.measure(world, poses, np.random.default_rng(1))
    truth = laser.true_ranges(world, poses)
    err = (r - truth)[np.isfinite(r)]
    assert abs(err.mean()) < 0.002
    assert err.std() == pytest.approx(0.02, rel=0.05)
    # quantized to the mm unit
    np.testing.assert_allclose(
        r[np.isfinite(r)] * 1000, np.round(r[np.isfinite(r)] * 1000), atol=0.01
    )


def test_mixed_pixels_lie_between_foreground_and_background() -> None:
    b = _box_corridor(width=6.0, length=30.0)
    b.circle(4.0, 0.0, 0.3)  # a column ahead: depth edges on both of its sides
    world = b.build()
    laser = LaserModel(mount_x=0.0, range_sigma=0.0, mixed_prob=1.0, glass_return_prob=0.0)
    poses = np.tile([0.5, 0.0, 0.0], (50, 1))
    r = laser.measure(world, poses, np.random.default_rng(2))
    clean = LaserModel(mount_x=0.0, **NOISELESS).measure(
        world, poses[:1], np.random.default_rng(2)
    )[0]
    changed = np.abs(r - clean) > 0.02
    assert changed.any(axis=1).all()  # every scan has mixed pixels at the column's edges
    cols = np.unique(np.nonzero(changed)[1])
    assert len(cols) <= 4  # only beams next to the two depth edges
    for c in cols:
        lo = min(clean[c - 1 : c + 2])
        hi = max(clean[c - 1 : c + 2])
        assert (r[changed[:, c], c] >= lo - 0.01).all() and (r[changed[:, c], c] <= hi + 0.01).all()


def _straight(length: float = 50.0, n: int = 1001) -> np.ndarray:
    return np.column_stack([np.linspace(0, length, n), np.zeros(n), np.zeros(n)])


def test_zero_noise_odometry_equals_truth() -> None:
    truth, _ = sample_path(np.array([(0, 0), (10, 0), (10, 8), (2, 3)]), 700, 0.4, 0.5)
    model = OdometryModel(wheel_diff=0, scale_error=0, wheel_noise=0, slip_prob=0)
    odo = model.integrate(truth, np.random.default_rng(0))
    np.testing.assert_allclose(odo[:, :2], truth[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.cos(odo[:, 2] - truth[:, 2]), 1.0, atol=1e-12)


def test_unequal_wheels_make_a_heading_drift_that_grows_with_distance() -> None:
    model = OdometryModel(wheel_diff=0.002, scale_error=0, wheel_noise=0, slip_prob=0)
    odo = model.integrate(_straight(), np.random.default_rng(0))
    drift = np.unwrap(odo[:, 2])
    distance = np.linspace(0, 50, len(drift))
    # dθ/ds = wheel_diff / wheel_base, a steady turn to the left (right wheel larger)
    np.testing.assert_allclose(drift, distance * 0.002 / 0.33, rtol=1e-3, atol=1e-9)
    assert odo[-1, 1] > 1.0  # the straight run became a curve


def test_scale_error_stretches_distance_and_noise_grows_like_a_random_walk() -> None:
    scaled = OdometryModel(wheel_diff=0, scale_error=0.05, wheel_noise=0, slip_prob=0)
    odo = scaled.integrate(_straight(), np.random.default_rng(0))
    assert odo[-1, 0] == pytest.approx(52.5, rel=1e-9)
    noisy = OdometryModel(wheel_diff=0, scale_error=0, wheel_noise=0.01, slip_prob=0)
    finals = np.array(
        [noisy.integrate(_straight(n=201), np.random.default_rng(s))[-1, 2] for s in range(60)]
    )
    # heading noise per step: sqrt(2) * k * sqrt(step) / b; 200 steps of 0.25 m
    expected = np.sqrt(200) * np.sqrt(2) * 0.01 * np.sqrt(0.25) / 0.33
    assert finals.std() == pytest.approx(expected, rel=0.3)


def test_slips_jump_the_heading() -> None:
    model = OdometryModel(wheel_diff=0, scale_error=0, wheel_noise=0, slip_prob=0.05)
    odo = model.integrate(_straight(), np.random.default_rng(3))
    jumps = np.abs(np.diff(odo[:, 2])) > 1e-6
    assert 20 < jumps.sum() < 80  # about 5 % of 1000 steps


@pytest.mark.parametrize("scenario", ["corridor", "building"])
def test_labels_and_regions_are_consistent(scenario: str) -> None:
    sim = simulate(scenario, seed=0, scans=1500 if scenario == "corridor" else 2500)
    t = sim.dataset.t
    assert len(sim.regions) >= 3
    assert list(sim.regions.columns) == ["feature", "start", "end"]
    assert (sim.regions.groupby("feature", sort=False).size() == 2).all()  # two halves
    taught = {}
    for row in sim.regions.itertuples():
        inside = np.flatnonzero((t >= row.start) & (t <= row.end))
        assert len(inside) == 5 and np.ptp(inside) == 4  # consecutive
        assert (sim.labels[inside] == row.feature).all()
        taught.setdefault(row.feature, []).append(inside)
    assert "none" not in taught
    for feature, (early, late) in taught.items():
        # in the two halves of the same occurrence of the place, its first run of labels
        first, last = next((a, b) for label, a, b in runs(sim.labels) if label == feature)
        assert first <= early[0] and late[-1] <= last, feature
        # a quarter and three quarters of the way by distance driven, not by scan count
        gt = sim.dataset.groundtruth
        driven = sim.distance()
        way = driven[first : last + 1] - driven[first]
        step = np.diff(way).max()
        for span, share in ((early, 0.25), (late, 0.75)):
            assert abs(way[span[2] - first] - share * way[-1]) <= step + 1e-9, feature
        if feature == "corner":  # the robot turns on the spot between them: arriving, leaving
            theta = gt.theta.to_numpy()
            turned = np.remainder(theta[late[2]] - theta[early[2]] + np.pi, 2 * np.pi) - np.pi
            assert abs(abs(turned) - np.pi / 2) < 0.05


def test_regions_standing_still_fall_back_to_scan_order() -> None:
    t = np.arange(40.0)
    labels = np.array(["a"] * 40)
    by_scan = training_regions(t, labels)
    still = training_regions(t, labels, along=np.zeros(40))
    moving = training_regions(t, labels, along=np.arange(40.0) ** 2)  # speeding up
    assert by_scan.equals(still) and by_scan[["start", "end"]].values.tolist() == [
        [8, 12],
        [28, 32],
    ]
    assert moving[["start", "end"]].values.tolist() == [[18, 22], [32, 36]]  # sqrt(1/4, 3/4)*39


def test_corridor_has_the_papers_sections_and_features(corridor_sim: Simulation) -> None:
    sim = corridor_sim
    assert sim.dataset.ranges.shape == (2000, 181)
    assert np.bincount(sim.sections).tolist() == [250] * 8
    assert set(sim.regions.feature) == {"window_a", "window_b", "door", "corner"}
    rate = 1 / np.median(np.diff(sim.dataset.t))
    assert 4 < rate < 10


def test_labels_are_geometrically_honest(corridor_sim: Simulation) -> None:
    """Every door scan sees into a room on the right, window_b scans see through the glass;
    plain corridor scans mostly do not. The scans beside a column (a landmark, not a place)
    are plain corridor, "none", and have the column close on their left."""
    sim = corridor_sim
    r = sim.dataset.ranges
    deg = np.rad2deg(sim.dataset.angles)
    gt = sim.dataset.groundtruth
    assert gt is not None
    door, window, plain = (sim.labels == k for k in ("door", "window_b", "none"))
    y = gt.y.to_numpy()
    leg_a, leg_b = plain & (gt.x.to_numpy() < 78), plain & (y > 3)
    laser_y = y + 0.16  # leg B heads +y; the laser is 0.16 m ahead of the robot's centre
    offset = (laser_y - 10.0) % 8.0  # columns every 8 m from y = 10 to 74, on the left wall
    column = (laser_y > 9) & (laser_y < 74.2) & ((offset >= 7.1) | (offset <= 0.1))

    right = (deg >= -90) & (deg <= -40)  # lateral reach beyond the right wall (1.2 m away)
    beyond = np.nanmax(np.abs(r[:, right] * np.sin(np.deg2rad(deg[right]))), axis=1) > 1.6
    assert beyond[door].all() and beyond[leg_a].mean() < 0.15

    left = (deg >= 45) & (deg <= 90)  # something nearer than the left wall (1.2 m away)
    near = np.nanmin(r[:, left] * np.sin(np.deg2rad(deg[left])), axis=1) < 0.9
    assert column.sum() > 80 and (sim.labels[column] == "none").all()
    assert near[column].all() and near[leg_b & ~column].mean() < 0.1

    through = np.isnan(r[:, 160])  # +70°: through the window at 20° from its normal
    assert through[window].mean() > 0.8 and through[plain].mean() < 0.1


def test_same_seed_same_log_other_seed_other_noise() -> None:
    a = simulate("building", seed=5, scans=300)
    b = simulate("building", seed=5, scans=300)
    c = simulate("building", seed=6, scans=300)
    np.testing.assert_array_equal(a.dataset.ranges, b.dataset.ranges)
    assert a.dataset.odometry is not None and b.dataset.odometry is not None
    np.testing.assert_array_equal(a.dataset.odometry.to_numpy(), b.dataset.odometry.to_numpy())
    assert not np.array_equal(a.dataset.ranges, c.dataset.ranges, equal_nan=True)
    assert a.dataset.groundtruth is not None and c.dataset.groundtruth is not None
    np.testing.assert_array_equal(
        a.dataset.groundtruth.to_numpy(), c.dataset.groundtruth.to_numpy()
    )


def test_unknown_parameter_is_a_clear_error() -> None:
    with pytest.raises(ToolkitError, match="unknown simulator parameter"):
        simulate("corridor", range_noise=0.1)
    with pytest.raises(ToolkitError, match="unknown scenario"):
        simulate("castle")
    with pytest.raises(ToolkitError, match="units"):
        simulate("corridor", units="inch")
    with pytest.raises(ToolkitError, match="scans=many for the simulator: expected integer"):
        simulate("corridor", scans="many")


def test_sway_swings_the_heading_about_the_path_and_leaves_the_default_log_as_it_was() -> None:
    plain = simulate("building", seed=5, scans=300)
    zero = simulate("building", seed=5, scans=300, sway=0)
    np.testing.assert_array_equal(plain.dataset.ranges, zero.dataset.ranges)
    assert plain.params == zero.params and "sway" not in plain.params
    held = simulate("building", seed=5, scans=300, sway="0.5", sway_period=2)
    assert held.params["sway"] == 0.5 and held.params["sway_period"] == 2.0
    a, b = plain.dataset.groundtruth, held.dataset.groundtruth
    assert a is not None and b is not None
    np.testing.assert_array_equal(a[["x", "y"]].to_numpy(), b[["x", "y"]].to_numpy())
    t = plain.dataset.t - plain.dataset.t[0]
    swing = b["theta"].to_numpy() - a["theta"].to_numpy()
    # t is kept to the ms, the swing drawn at the exact times: 1.6 rad/s x 0.5 ms at most
    np.testing.assert_allclose(swing, 0.5 * np.sin(np.pi * t), atol=1e-3)
    assert not np.array_equal(plain.dataset.ranges, held.dataset.ranges, equal_nan=True)
    with pytest.raises(ToolkitError, match="sway must be at least 0"):
        simulate("corridor", sway=-0.1)
    with pytest.raises(ToolkitError, match="sway_period=soon for the simulator"):
        simulate("corridor", sway=0.1, sway_period="soon")
