"""The mapper's fast paths give, to the bit, what the plain computations they replace give,
on the simulator's building with drifted odometry: a keyframe's surfaces placed in one numba
pass, the loop closer's fine grid stamped only where no occupied neighbour is nearer, the
scan-to-map search's fine grid computed over the searched box only, and the grid rebuilt in
the old grid's memory. (Identical results are what lets a speed-up keep every ATE and loop.)"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from toolkit import se2
from toolkit.dataset import Dataset, LaserGeometry
from toolkit.poses import odometry_poses, truth_poses, with_drift
from toolkit.sim import Simulation
from toolkit.slam.grid import LikelihoodGrid, _disc_field, correlative_search, stamp_segments
from toolkit.slam.loops import LoopCloser
from toolkit.slam.scanmap import MapConfig, MapMatcher, _placed_surfaces


@pytest.fixture(scope="module")
def drifted(building_sim: Simulation) -> Dataset:
    return with_drift(building_sim.dataset, 0)


def _surfaces_numpy(
    pose: np.ndarray, ranges: np.ndarray, laser: LaserGeometry, config: MapConfig
) -> np.ndarray:
    """The numpy computation `_placed_surfaces` replaced: the surfaces in the robot frame,
    then placed at `pose`."""
    mount = se2.mount_pose(laser)
    a = laser.angles + mount[2]
    r = np.asarray(ranges, dtype=np.float64)
    x = mount[0] + r * np.cos(a)
    y = mount[1] + r * np.sin(a)
    ok = np.isfinite(r) & (r > 0) & (r <= config.max_range + config.map_margin)
    p = np.column_stack([x, y])
    seg = p[1:] - p[:-1]
    length = np.hypot(seg[:, 0], seg[:, 1])
    reach = 0.05 + config.join * np.abs(laser.angle_increment) * np.fmin(r[1:], r[:-1])
    both = ok[1:] & ok[:-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = seg / length[:, None]
    cos_prev = np.nan_to_num(np.abs(np.einsum("ij,ij->i", u[1:], u[:-1])))
    limit = math.cos(config.join_angle)
    in_line = np.zeros(len(seg), dtype=bool)
    in_line[1:] |= cos_prev > limit
    in_line[:-1] |= cos_prev > limit
    join = both & ((length < reach) | (in_line & (length < config.join_max)))
    joined = np.zeros(len(r), dtype=bool)
    joined[1:] |= join
    joined[:-1] |= join
    lone = ok & ~joined & (r <= config.lone_range)
    k = np.nonzero(join)[0]
    local = np.concatenate([np.column_stack([p[k], p[k + 1]]), np.column_stack([p[lone], p[lone]])])
    c, s = math.cos(pose[2]), math.sin(pose[2])
    out = np.empty_like(local)
    out[:, 0::2] = pose[0] + c * local[:, 0::2] - s * local[:, 1::2]
    out[:, 1::2] = pose[1] + s * local[:, 0::2] + c * local[:, 1::2]
    return out


@pytest.mark.parametrize(
    "config", [MapConfig(), MapConfig(lone_range=8.0, join_max=0.5, max_range=10.0)]
)
def test_placed_surfaces_in_one_pass_equal_surfaces_then_place(
    drifted: Dataset, config: MapConfig
) -> None:
    ds = drifted
    mount = se2.mount_pose(ds.laser)
    cos_a = np.cos(ds.laser.angles + mount[2])
    sin_a = np.sin(ds.laser.angles + mount[2])
    rng = np.random.default_rng(0)
    ranges = ds.ranges[::97].astype(np.float64)
    ranges[3, 100:140] = np.nan  # missing returns
    ranges[4, 10:12] = np.inf
    counts = []
    for r in ranges:
        pose = np.array([*rng.normal(0.0, 30.0, 2), rng.uniform(-np.pi, np.pi)])
        with np.errstate(invalid="ignore"):  # inf - inf: the returns left out
            want = _surfaces_numpy(pose, r, ds.laser, config)
        got = _placed_surfaces(
            r,
            cos_a,
            sin_a,
            mount,
            config.max_range + config.map_margin,
            config.join * abs(ds.laser.angle_increment),
            math.cos(config.join_angle),
            config.join_max,
            config.lone_range,
            pose,
        )
        np.testing.assert_array_equal(got, want)
        counts.append(len(want))
    assert min(counts) > 50  # real surfaces, not empty arrays compared


def test_fine_window_stamping_equals_the_exact_distance_transform(drifted: Dataset) -> None:
    """`_disc_field` (each occupied cell stamps only where no neighbour is nearer) against the
    exact squared cell distances of scipy's Euclidean distance transform, truncated."""
    ds = drifted
    odo = odometry_poses(ds)
    assert odo is not None
    closer = LoopCloser(ds.ranges, ds.laser)
    pts = closer._local(1000, np.arange(950, 1050, 5), odo)
    res = 0.04
    lo = pts.min(axis=0) - 0.5
    cells = np.floor((pts - lo) / res).astype(np.int64)
    w, h = (cells.max(axis=0) + 12).tolist()
    cells = np.concatenate([cells, [[0, 0], [w - 1, h - 1]]])  # the corners: the edges
    for r in (1, 4, 15):
        far = r * r + 1
        table = np.arange(far + 1, dtype=np.float32)  # the squared distance itself
        dist, like_t = _disc_field(np.ascontiguousarray(cells), h, w, r, table, -table)
        free = np.ones((h, w), dtype=bool)
        free[cells[:, 1], cells[:, 0]] = False
        d2 = np.rint(distance_transform_edt(free) ** 2).astype(np.int64)
        want = np.minimum(d2, far).astype(np.float32)
        np.testing.assert_array_equal(dist, want)
        np.testing.assert_array_equal(like_t, -want.T)
        assert (want < far).mean() > (0.05 if r == 15 else 0.005)  # walls, not empty


def _matcher_until(ds: Dataset, odo: np.ndarray, stop: int, config: MapConfig) -> MapMatcher:
    m = MapMatcher(ds.laser, config)
    for k in range(stop):
        m.push(ds.ranges[k], odo[k], float(ds.t[k]))
    return m


def test_search_on_the_box_grid_finds_what_the_whole_grid_finds(drifted: Dataset) -> None:
    ds = drifted
    odo = odometry_poses(ds)
    truth = truth_poses(ds)
    assert odo is not None and truth is not None
    config = MapConfig()
    rng = np.random.default_rng(1)
    searched = 0
    for stop in (400, 1500, 2600):
        m = _matcher_until(ds, odo, stop, config)
        coarse, fine = m._search_grids()
        _, crop, corner = m._search_maps()
        whole = LikelihoodGrid.from_distance(crop, corner, config.resolution, 0.08, config.cap)
        r = ds.ranges[stop].astype(np.float64)
        ok = np.isfinite(r) & (r > 0) & (r <= config.max_range)
        pts = np.column_stack([r[ok] * m._cos[ok], r[ok] * m._sin[ok]]) + m._mount[:2]
        for _ in range(4):
            predicted = m._last + np.array([*rng.normal(0.0, 0.4, 2), rng.normal(0.0, 0.3)])
            found = [
                correlative_search(
                    coarse,
                    grid,
                    pts,
                    predicted,
                    window=config.search_window,
                    turn=config.search_turn,
                    turn_step=0.02,
                    coarse_voxel=0.2,
                    fine_resolution=config.resolution,
                )
                for grid in (whole, fine)
            ]
            np.testing.assert_array_equal(found[0].pose, found[1].pose)
            assert found[0].score == found[1].score
            assert found[0].coarse_score == found[1].coarse_score
            assert found[0].runner_up == found[1].runner_up
            assert found[0].inliers == found[1].inliers
            searched += 1
            # the search found the scan's place (the box held what it needed)
            assert np.hypot(*(found[1].pose[:2] - m._last[:2])) < 1.5
    assert searched == 12


def test_a_recentred_grid_equals_a_fresh_grid_of_the_window(drifted: Dataset) -> None:
    """The rebuilt grid reuses the old grid's memory: right after each recentring it holds
    exactly a fresh grid with the window's keyframes stamped."""
    ds = drifted
    odo = odometry_poses(ds)
    assert odo is not None
    config = replace(MapConfig(), recentre=2.0)
    m = MapMatcher(ds.laser, config)
    checked = 0
    centre = None
    for k in range(1200):
        m.push(ds.ranges[k], odo[k], float(ds.t[k]))
        assert m._grid is not None
        if centre is not None and not np.array_equal(centre, m._centre):
            origin, dist = m._grid
            fresh = np.full(dist.shape, config.cap, dtype=np.float32)
            for _, _, q in m._keys:
                stamp_segments(fresh, origin, config.resolution, q, config.cap)
            np.testing.assert_array_equal(dist, fresh)
            checked += 1
        centre = m._centre.copy()
    assert checked >= 5
