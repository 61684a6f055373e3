"""The mapper's fast paths give, to the bit, what the plain computations they replace give,
on the simulator's building with drifted odometry: a keyframe's surfaces placed in one numba
pass, the loop closer's fine grid stamped only where no occupied neighbour is nearer, the
scan-to-map search's fine grid computed over the searched box only, the grid rebuilt in
the old grid's memory, and the correlative search's coarse level by branch and bound.
(Identical results are what lets a speed-up keep every ATE and loop.)"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from tests.slam.conftest import loop_candidates, reference_grids
from toolkit import se2
from toolkit.dataset import Dataset, LaserGeometry
from toolkit.poses import odometry_poses, truth_poses, with_drift
from toolkit.se2 import between
from toolkit.sim import Simulation
from toolkit.slam import grid as grid_mod
from toolkit.slam.grid import (
    LikelihoodGrid,
    SearchResult,
    _disc_field,
    correlative_search,
    stamp_segments,
    voxel_subsample,
)
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
    pts = closer.local_points(1000, np.arange(950, 1050, 5), odo)
    res = 0.04
    lo = pts.min(axis=0) - 0.5
    cells = np.floor((pts - lo) / res).astype(np.int64)
    w, h = (cells.max(axis=0) + 12).tolist()
    cells = np.concatenate([cells, [[0, 0], [w - 1, h - 1]]])  # the corners: the edges
    for r in (1, 4, 15, 16):  # 16: squared distances past a byte
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


def _returns(m: MapMatcher, ranges: np.ndarray) -> np.ndarray:
    """A scan's returns in the robot frame, as the front end places them."""
    r = ranges.astype(np.float64)
    ok = np.isfinite(r) & (r > 0) & (r <= m.config.max_range)
    return np.column_stack([r[ok] * m._cos[ok], r[ok] * m._sin[ok]]) + m._mount[:2]


def _front_search(
    m: MapMatcher,
    fine: LikelihoodGrid | Callable[[np.ndarray, np.ndarray], LikelihoodGrid],
    pts: np.ndarray,
    predicted: np.ndarray,
    **kw: bool,
) -> SearchResult:
    """The front end's correlative search on `m`'s coarse grid and `fine`."""
    config = m.config
    coarse, _ = m._search_grids()
    return correlative_search(
        coarse,
        fine,
        pts,
        predicted,
        window=config.search_window,
        turn=config.search_turn,
        turn_step=0.02,
        coarse_voxel=0.2,
        fine_resolution=config.resolution,
        **kw,
    )


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
        _, fine = m._search_grids()
        _, crop, corner = m._search_maps()
        whole = LikelihoodGrid.from_distance(crop, corner, config.resolution, 0.08, config.cap)
        pts = _returns(m, ds.ranges[stop])
        for _ in range(4):
            predicted = m._last + np.array([*rng.normal(0.0, 0.4, 2), rng.normal(0.0, 0.3)])
            found = [_front_search(m, grid, pts, predicted) for grid in (whole, fine)]
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


def _pyramid_numpy(like_t: np.ndarray, levels: int) -> np.ndarray:
    """Level L, cell (x + P, y + P): the largest of like_t over [x, x + 2^L) x [y, y + 2^L),
    0 off the grid (the plain computation `_pyramid` does in one pass per level)."""
    w, h = like_t.shape
    p = 1 << (levels - 1)
    big = np.zeros((w + 3 * p, h + 3 * p), dtype=np.float32)
    big[p : p + w, p : p + h] = like_t
    out = np.zeros((levels, w + 2 * p, h + 2 * p), dtype=np.float32)
    for lv in range(levels):
        s = 1 << lv
        for dx in range(s):
            for dy in range(s):
                out[lv] = np.maximum(out[lv], big[dx : dx + w + 2 * p, dy : dy + h + 2 * p])
    return out


def _same(a: SearchResult, b: SearchResult) -> None:
    np.testing.assert_array_equal(a.pose, b.pose)
    assert (a.score, a.coarse_score, a.runner_up, a.inliers) == (
        b.score,
        b.coarse_score,
        b.runner_up,
        b.inliers,
    )


def test_branch_and_bound_finds_what_the_exhaustive_coarse_search_finds(
    drifted: Dataset, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The coarse level by branch and bound (poses best first, blocks bounded by max-pooled
    grids) against scoring every coarse pose: the same starts, winner's score and runner-up,
    so the same search result to the bit, for the loop closer's searches (a 3 m window at
    the building's loop candidates, predictions off by up to a metre) and the front end's (a
    1 m, 1 rad window at random predictions); and it did bound (no fallback to the
    exhaustive search in most of them)."""
    ds = drifted
    odo = odometry_poses(ds)
    assert odo is not None
    bounded = []
    real = grid_mod._bounded_starts

    def spy(*args: object, **kwargs: object) -> object:
        out = real(*args, **kwargs)  # type: ignore[arg-type]
        bounded.append(out is not None)
        return out

    monkeypatch.setattr(grid_mod, "_bounded_starts", spy)
    rng = np.random.default_rng(3)
    wins = 0
    # the loop closer's: the building's loop candidates, scans placed by the truth
    truth = truth_poses(ds)
    assert truth is not None
    closer, keys, along, pairs = loop_candidates(ds, truth)
    cfg = closer.config
    assert len(pairs) >= 8
    for a, b, _ in pairs[:12]:
        query = voxel_subsample(closer.local_points(b, np.array([b - 2, b, b + 2]), truth), 0.1)
        _, coarse, fine = reference_grids(closer, a, truth, along, keys)
        prediction = between(truth[a], truth[b]) + np.array([*rng.normal(0, 0.5, 2), 0.1])
        found = [
            correlative_search(
                coarse,
                fine,
                query,
                prediction,
                window=3.0,
                turn=cfg.turn,
                turn_step=cfg.turn_step,
                coarse_voxel=cfg.coarse_voxel,
                exhaustive=full,
            )
            for full in (False, True)
        ]
        _same(*found)
        wins += found[0].inliers > 0.6
    assert wins >= 6  # real matches, not empty searches compared
    # the front end's
    config = MapConfig()
    for stop in (300, 1200, 2400):
        m = _matcher_until(ds, odo, stop, config)
        _, fine_over = m._search_grids()
        pts = _returns(m, ds.ranges[stop])
        for _ in range(4):
            predicted = m._last + np.array([*rng.normal(0.0, 0.4, 2), rng.normal(0.0, 0.3)])
            found = [
                _front_search(m, fine_over, pts, predicted, exhaustive=full)
                for full in (False, True)
            ]
            _same(*found)
    assert len(bounded) == min(len(pairs), 12) + 12
    assert sum(bounded) >= len(bounded) - 3
    # the pyramid it bounds with (8 levels: a wide window's, padding wider than the grid)
    for levels in (1, 3, 5, 8):
        np.testing.assert_array_equal(
            grid_mod._pyramid(coarse.likelihood_t, levels),
            _pyramid_numpy(coarse.likelihood_t, levels),
        )
    # the offsets near a pick, computed in a box around it only: `_within`'s booleans
    for step, window, reach in ((0.2, 3.0, 0.3), (0.2, 12.0, 0.6), (0.1, 0.5, 0.3)):
        half, offsets, _ = grid_mod._lattice(step, window, 0.1, 0.05)
        for i, j in ((0, 0), (half, half), (2 * half, 1), (3, 2 * half - 2)):
            near = grid_mod._within_near(offsets, i, j, reach, step)[0]
            np.testing.assert_array_equal(near, grid_mod._within(offsets, i, j, reach))


def _build_edt(
    points: np.ndarray, resolution: float, sigma: float, margin: float, cap: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`LikelihoodGrid.build` by scipy's distance transform of the whole grid (what the disc
    stamping replaced): its corner, distances and likelihoods."""
    pts = np.asarray(points, dtype=np.float64)
    lo = pts.min(axis=0) - margin
    shape = np.ceil((pts.max(axis=0) + margin - lo) / resolution).astype(np.int64) + 1
    ij = np.floor((pts - lo) / resolution).astype(np.int64)
    free = np.ones((shape[1], shape[0]), dtype=bool)
    free[ij[:, 1], ij[:, 0]] = False
    dist = np.minimum(distance_transform_edt(free) * resolution, cap).astype(np.float32)
    like = np.exp(-(dist.astype(np.float64) ** 2) / (2 * sigma * sigma)).astype(np.float32)
    return lo, dist, like


def test_coarse_grid_by_discs_equals_the_distance_transform(drifted: Dataset) -> None:
    """`LikelihoodGrid.build` stamping the disc within the cap around each occupied cell, to
    the bit what the distance transform of the whole grid gives, on a loop test's reference
    map (a few keyframes' returns) at the searches' 0.2 m and at resolutions where the cap is
    not a whole number of cells."""
    ds = drifted
    truth = truth_poses(ds)
    assert truth is not None
    closer = LoopCloser(ds.ranges, ds.laser)
    checked = 0
    for centre in (400, 1500, 2600):
        ref = closer.local_points(centre, np.arange(centre - 40, centre + 40, 8), truth)
        for res, sigma, margin, cap in (
            (0.2, 0.25, 1.0, 2.0),
            (0.2, 0.25, 1.5, 2.0),
            (0.15, 0.3, 1.0, 2.0),
            (0.3, 0.25, 0.5, 1.0),
        ):
            assert math.ceil(cap / res) <= grid_mod._DISC_CELLS  # the disc path
            grid = LikelihoodGrid.build(ref, res, sigma, margin=margin, cap=cap)
            lo, dist, like = _build_edt(ref, res, sigma, margin, cap)
            np.testing.assert_array_equal(grid.origin, lo)
            np.testing.assert_array_equal(grid.distance, dist)
            np.testing.assert_array_equal(grid.likelihood, like)
            np.testing.assert_array_equal(grid.likelihood_t, like.T)
            assert grid.likelihood.flags.c_contiguous and grid.likelihood_t.flags.c_contiguous
            assert (dist == 0).mean() > 0.01 and len(np.unique(dist)) > 5  # walls, not a blank
            checked += 1
    assert checked == 12


def test_bounded_walk_gives_the_whole_volumes_picks() -> None:
    """`_bounded_starts` (its walk one numba call, `_bnb_picks`) against the whole coarse
    volume on random grids: the same picks (3, each the best pose not next to one picked
    before), the winner's score and the runner-up (the best pose far from the winner), or
    None where the volume's picks have equal scores (binary grids: plateaus of equal sums),
    which the caller then resolves from the whole volume (`_starts_sorted`)."""
    rng = np.random.default_rng(5)
    step, turn_step, away, away_turn = 0.1, 0.05, 0.3, 0.15
    half, offsets, thetas = grid_mod._lattice(step, 0.5, 0.3, turn_step)
    agreed = ties = 0
    for trial in range(60):
        # a map of a few walls; the query some of their points; every third grid binary
        ends = rng.uniform(-3.0, 3.0, (6, 2, 2))
        walls = np.concatenate([a + np.linspace(0, 1, 40)[:, None] * (b - a) for a, b in ends])
        built = LikelihoodGrid.build(walls, step, 0.25)
        like = built.likelihood
        if trial % 3 == 2:
            like = (like > 0.5).astype(np.float32)
        grid = LikelihoodGrid(built.origin, step, like, np.ascontiguousarray(like.T), like)
        pts = walls[rng.choice(len(walls), int(rng.integers(5, 60)), replace=False)]
        prediction = np.array([*rng.normal(0.0, 0.2, 2), rng.normal(0.0, 0.1)])
        got = grid_mod._bounded_starts(
            grid, pts, prediction, thetas, half, offsets, turn_step, 3, away, away_turn
        )
        vol = grid_mod._search(grid.likelihood_t, grid.origin, step, pts, prediction, thetas, half)
        picks = grid_mod._starts(vol, offsets, thetas, step, turn_step, 3)
        if got is None:
            ties += picks is None
            continue
        assert picks is not None and got[0] == picks
        far = grid_mod._far(offsets, thetas, *picks[0], away, away_turn)
        assert got[1] == vol[picks[0]]
        assert got[2] == (vol[far].max() if far.any() else 0.0)
        agreed += 1
    assert agreed >= 30 and ties >= 5


def test_search_equals_its_sums_in_point_order() -> None:
    """`grid._search` (a run of every y offset when all are on the grid, a clipped one
    otherwise) against the sums it stands for, point by point in order in float64, 0 off the
    grid: equal to the bit, on random grids with queries over the edges."""
    rng = np.random.default_rng(7)
    for trial in range(20):
        res, half = (0.04, 5) if trial % 2 else (0.2, 7)
        like = rng.random((int(rng.integers(8, 40)), int(rng.integers(8, 40)))).astype(np.float32)
        origin = rng.normal(0.0, 0.5, 2)
        pts = rng.uniform(-1.0, 1.0, (int(rng.integers(1, 50)), 2)) * like.shape[::-1] * res
        centre = np.array([*(origin + np.array(like.shape[::-1]) * res / 2), rng.normal()])
        thetas = np.linspace(-0.1, 0.1, 5)
        got = grid_mod._search(np.ascontiguousarray(like.T), origin, res, pts, centre, thetas, half)
        n = 2 * half + 1
        want = np.zeros((len(thetas), n, n))
        padded = np.zeros((like.shape[0] + 4 * n, like.shape[1] + 4 * n))
        padded[2 * n : -2 * n, 2 * n : -2 * n] = like
        for a, th in enumerate(thetas):
            c, s = math.cos(centre[2] + th), math.sin(centre[2] + th)
            acc = np.zeros((n, n))
            for x, y in pts:
                i = math.floor((centre[0] + c * x - s * y - origin[0]) * (1.0 / res)) - half
                j = math.floor((centre[1] + s * x + c * y - origin[1]) * (1.0 / res)) - half
                i, j = np.clip(i, -2 * n, like.shape[1] + n), np.clip(j, -2 * n, like.shape[0] + n)
                acc += padded[j + 2 * n : j + 3 * n, i + 2 * n : i + 3 * n].T
            want[a] = acc / len(pts)
        assert np.array_equal(got, want)


def test_local_returns_in_one_pass_equal_the_numpy_form(drifted: Dataset) -> None:
    """`LoopCloser.local_points` (one numba pass, `_placed_returns`) against the numpy form it
    replaced, on random scan sets of the building: equal to the bit."""
    closer = LoopCloser(drifted.ranges, drifted.laser)
    odo = odometry_poses(drifted)
    assert odo is not None
    rng = np.random.default_rng(3)
    for _ in range(50):
        centre = int(rng.integers(0, len(odo)))
        scans = np.sort(rng.choice(len(odo), int(rng.integers(1, 20)), replace=False))
        rel = between(np.broadcast_to(odo[centre], (len(scans), 3)), odo[scans])
        r = drifted.ranges[scans].astype(np.float64)
        x = closer._mount[0] + r * closer._cos
        y = closer._mount[1] + r * closer._sin
        ok = np.isfinite(r) & (np.hypot(x, y) <= closer.config.max_range)
        c, s = np.cos(rel[:, 2:3]), np.sin(rel[:, 2:3])
        want = np.column_stack(
            [(rel[:, :1] + c * x - s * y)[ok], (rel[:, 1:2] + s * x + c * y)[ok]]
        )
        assert np.array_equal(closer.local_points(centre, scans, odo), want)


def test_box_selections_in_one_pass_equal_the_numpy_forms() -> None:
    """`inside` (a search's reference points within reach) and `_cells_within` (a fine
    window's cells) keep the rows numpy's broadcast compares keep, in their order, points on
    the box's edges included (their coordinates drawn from the edges themselves)."""
    rng = np.random.default_rng(3)
    for n in (0, 1, 7, 3000):
        lo, hi = rng.normal(size=2) - 3.0, rng.normal(size=2) + 3.0
        pts = rng.normal(size=(n, 2)) * 5.0
        on_edge = rng.random(size=(n, 2)) < 0.1
        pts[on_edge] = np.where(rng.random(size=(n, 2)) < 0.5, lo, hi)[on_edge]
        want = pts[((pts >= lo) & (pts <= hi)).all(axis=1)]
        got = grid_mod.inside(pts, lo, hi)
        assert got.shape == want.shape and np.array_equal(got, want)
        assert 0 < len(got) < n or n < 10
        ij = np.floor(pts / 0.04).astype(np.int64)
        i0, i1 = np.floor(lo / 0.04).astype(np.int64), np.ceil(hi / 0.04).astype(np.int64)
        cells = grid_mod._cells_within(ij, i0, i1)
        keep = ((ij >= i0) & (ij < i1)).all(axis=1)
        assert cells.flags.c_contiguous and np.array_equal(cells, ij[keep] - i0)


def test_loops_verified_in_threads_are_the_loops_verified_one_by_one(
    drifted: Dataset, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A round's candidates verified side by side (`LoopCloser.workers`) give the mapper's
    loops, verdicts and poses of one thread, to the bit."""
    from toolkit.slam import loops as loops_mod
    from toolkit.slam.run import slam_trajectory

    runs = []
    for workers in (1, 2):
        monkeypatch.setattr(loops_mod, "WORKERS", workers)
        result, slam = slam_trajectory(drifted)
        verdicts = [(lp.a, lp.b, lp.pose.tobytes(), lp.accepted, lp.reason) for lp in slam.loops]
        runs.append((result.poses.tobytes(), verdicts))
    assert sum(accepted for *_, accepted, _ in runs[0][1]) >= 5
    assert runs[1] == runs[0]


def test_a_stop_while_verifying_in_threads_leaves_the_rest_unverified() -> None:
    """Ctrl-C while a round is verified in threads ends the round at once: the pairs not
    begun are dropped, not verified one after another before the stop lands."""
    import threading
    import time

    laser = LaserGeometry(beams=4, angle_min=-1.0, angle_increment=0.5, range_max=10.0)
    closer = LoopCloser(np.ones((3, 4)), laser)
    closer.workers = 2
    begun = []
    lock = threading.Lock()

    def check(item: int) -> None:
        with lock:
            begun.append(item)
        if item == 3:
            raise KeyboardInterrupt
        time.sleep(0.01)

    with pytest.raises(KeyboardInterrupt):
        closer.each(check, list(range(400)))
    assert 4 <= len(begun) < 40
