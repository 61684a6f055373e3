"""infinite-corridor drift seed 181 (1.06 m, issue #20; back32 in docs/journal/maps.md): every
step of the front end and every accepted loop is near the truth, and the run's excess error
is one rigid rotation of the part of the map west of the junction at x = -100 m (scans
1400-1799: 60 m of corridor and a 300 m one-pass rectangle), which hangs on the loops between
the corridor's passes there (the hinge). The loops' heading errors there (0.5 degrees RMS,
up to 2.1) turn it; set to the truth's, the same graph places it."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

import toolkit
from tests.slam.conftest import drifted_carmen
from toolkit import se2
from toolkit.metrics import align_se2, evaluate
from toolkit.poses import truth_poses
from toolkit.slam import graph as pg
from toolkit.slam.loops import Loop, loop_truth_error
from toolkit.slam.pipeline import SlamConfig, hang
from toolkit.slam.run import slam_trajectory

#: the part of the map beyond the hinge, and the scans b of the loops that hold it
PENINSULA = (1400, 1800)
HINGE = ((1330, 1400), (1740, 1830))


def _at_truth(lp: Loop, truth: np.ndarray) -> np.ndarray:
    """The loop's pose with the truth's relative pose, a corridor loop keeping its own
    position along its axis (there it claims nothing)."""
    rel = se2.between(truth[lp.a], truth[lp.b])
    if lp.axis is not None:
        rel[:2] += ((lp.pose[:2] - rel[:2]) @ lp.axis) * lp.axis
    return rel


def test_real_infinite_corridor_seed_181_excess_is_the_hinge_loops_heading(real: Path) -> None:
    """The default mapper on seed 181 (1.06 m when measured): no loop far off the truth; the
    peninsula refitted alone brings the run to the log's usual; and the same graph with the
    hinge loops' poses the truth's places it too, the other loops as measured."""
    ds = drifted_carmen(real, "infinite-corridor", seed=181)
    truth = truth_poses(ds)
    assert truth is not None
    config = SlamConfig()
    result, run = slam_trajectory(ds, slam=config)
    poses = result.poses
    accepted = [lp for lp in run.loops if lp.accepted]
    assert len(accepted) > 150
    # no loop is false, and none is far off: 0.26 m and 2.14 degrees at most (measured)
    errors = np.array([loop_truth_error(lp, truth) for lp in accepted])
    assert errors[:, 0].max() < 0.35 and errors[:, 1].max() < 2.5

    # the rest of the map aligned on the truth, the peninsula refitted alone (one rigid
    # motion): the ATE falls to the log's usual (0.32 m measured)
    idx = np.arange(len(poses))
    pen = (idx >= PENINSULA[0]) & (idx < PENINSULA[1])
    placed = se2.compose(np.broadcast_to(align_se2(poses[~pen], truth[~pen]), poses.shape), poses)
    fit = align_se2(placed[pen], truth[pen])
    refit = placed.copy()
    refit[pen] = se2.compose(np.broadcast_to(fit, (int(pen.sum()), 3)), placed[pen])
    assert evaluate(refit, truth)["ate"]["rmse"] < 0.4

    # the same graph (every sequential edge, every accepted loop) with the hinge loops' poses
    # the truth's and the other loops as measured: under 0.45 m (0.34 measured)
    def hinge(lp: Loop) -> bool:
        return any(lo <= lp.b < hi for lo, hi in HINGE)

    assert 20 < sum(hinge(lp) for lp in accepted) < 60
    fixed = [e for e in run.edges if not e.loop]
    loops = [
        pg.Edge(
            lp.a,
            lp.b,
            _at_truth(lp, truth) if hinge(lp) else lp.pose,
            lp.covariance(config.loop_sigma),
            loop=True,
        )
        for lp in accepted
    ]
    graph, values = pg.factor_graph(run.keys, run.before[run.keys], fixed + loops, config.robust)
    mended = hang(run.keys, run.before, pg.optimise(graph, values, run.keys))
    assert evaluate(mended, truth)["ate"]["rmse"] < 0.45


def _cross_pass_agreement(ds: toolkit.Dataset, turns: np.ndarray) -> np.ndarray:
    """Scans placed by the corrected poses with the peninsula turned about the hinge (scan
    1395's position) by each of `turns` (rad): over the pairs of scans from different passes
    (a outside the peninsula, b inside, more than 100 scans apart, within 10 m), the mean
    share of b's returns within 3 cm of a's."""
    from scipy.spatial import cKDTree

    truth = truth_poses(ds)
    assert truth is not None
    idx = np.arange(len(truth))
    pen = (idx >= PENINSULA[0]) & (idx < PENINSULA[1])
    apart = np.hypot(*(truth[:, None, :2] - truth[None, :, :2]).transpose(2, 0, 1))
    far = np.abs(idx[:, None] - idx[None, :]) > 100
    a_s, b_s = np.nonzero((~pen)[:, None] & pen[None, :] & far & (apart < 10.0))
    assert 60 < len(a_s) < 150  # 94: the passes overlap only near the junction
    beams = ds.laser.angles
    pivot = truth[1395, :2]

    def local(k: int) -> np.ndarray:
        r = ds.ranges[k].astype(np.float64)
        ok = np.isfinite(r) & (r < 20.0)
        return np.column_stack([r[ok] * np.cos(beams[ok]), r[ok] * np.sin(beams[ok])])

    def placed(k: int, turn: float) -> np.ndarray:
        pose = truth[k].copy()
        if pen[k]:
            pose[:2] = pivot + se2.rotation(turn) @ (pose[:2] - pivot)
            pose[2] += turn
        return pose[:2] + local(k) @ se2.rotation(pose[2]).T

    shares = np.zeros((len(a_s), len(turns)))
    for p, (a, b) in enumerate(zip(a_s, b_s, strict=True)):
        tree = cKDTree(placed(int(a), 0.0))
        for j, turn in enumerate(turns):
            near, _ = tree.query(placed(int(b), float(turn)), distance_upper_bound=0.3)
            shares[p, j] = np.mean(near < 0.03)
    result: np.ndarray = shares.mean(axis=0)
    return result


def test_real_infinite_corridor_truths_hinge_agrees_with_its_scans(real: Path) -> None:
    """The mapper's peninsula turns against the truth by a part common to every drift seed
    and direction (mean +0.53 degrees over seeds 0-190; back32). Is that the truth's? The scans
    say no: placed by the corrected poses, the two passes' overlapping scans at the junction
    agree best with the peninsula turned -0.1 degrees (peak -0.135; the truth's turn that would
    hold the common part is about -0.5), and worse at -0.5 than as corrected (share 0.0155
    against 0.0230). The log has no PARAM line (laser x 0) and every line's laser and robot
    poses are equal; turned revisits agree best with the laser at the pose (docs/journal/maps.md,
    session 34, ic34)."""
    from importers.carmen import Carmen, CarmenOptions

    path = real / "carmen_radish_corrected" / "infinite-corridor-corrected.log.gz"
    ds = Carmen().read([path], CarmenOptions(poses="groundtruth"))
    assert ds.laser.x == 0.0
    with gzip.open(path, "rt") as lines:
        flaser = [line.split() for line in lines if line.startswith("FLASER")]
    n_beams = int(flaser[0][1])
    assert len(flaser) == 1941
    assert all(f[n_beams + 2 : n_beams + 5] == f[n_beams + 5 : n_beams + 8] for f in flaser)
    turns_deg = np.round(np.arange(-1.0, 1.0001, 0.1), 1)
    shares = _cross_pass_agreement(ds, np.deg2rad(turns_deg))
    best = float(turns_deg[int(np.argmax(shares))])
    assert -0.3 <= best <= 0.3, (best, shares)
    at = dict(zip(turns_deg.tolist(), shares.tolist(), strict=True))
    assert at[0.0] > 1.3 * at[-0.5], at
    assert at[0.0] > 1.3 * at[0.5], at

    from tests.slam.test_slam import _turned_revisit_agreement

    at_pose = _turned_revisit_agreement(ds, 0.0)
    assert at_pose > 1.1 * max(_turned_revisit_agreement(ds, x) for x in (-0.04, 0.04))


def _wall_direction(ds: toolkit.Dataset, k: int, heading: float) -> float:
    """The corridor's direction in the world (degrees, folded to (-90, 90]) from scan `k` at
    `heading` (rad): a line fitted to each side wall (returns 0.5-4 m to the side and 1-15 m
    ahead), trimmed, kept when 4 m long or more and straight within 5 cm; NaN without one."""
    r = ds.ranges[k].astype(np.float64)
    ok = np.isfinite(r) & (r > 0.05) & (r < 30.0)
    beams = ds.laser.angles[ok]
    x, y = r[ok] * np.cos(beams), r[ok] * np.sin(beams)
    found = []
    for side in (1.0, -1.0):
        m = (side * y > 0.5) & (side * y < 4.0) & (np.abs(x) > 1.0) & (np.abs(x) < 15.0)
        xs, ys = x[m], y[m]
        if len(xs) < 8:
            continue
        for _ in range(3):
            slope, cut = np.polyfit(xs, ys, 1)
            res = ys - (slope * xs + cut)
            keep = np.abs(res) < 3 * (1.5 * np.median(np.abs(res)) + 0.01)
            if keep.sum() < 8:
                break
            xs, ys = xs[keep], ys[keep]
        if np.ptp(xs) >= 4.0 and np.std(ys - (slope * xs + cut)) <= 0.05:
            found.append((heading + np.arctan(slope) + np.pi / 2) % np.pi - np.pi / 2)
    return float(np.rad2deg(np.mean(found))) if found else float("nan")


def test_real_infinite_corridor_front_end_turns_where_the_return_pass_crosses_the_junction(
    real: Path,
) -> None:
    """Where the peninsula's common turn comes from (docs/journal/maps.md, session 37, ic37):
    the scan-to-map front end, even with the truth as its odometry, turns about +0.7 degrees
    that the truth does not where the return pass enters the junction's open area (scan 1793,
    x = -126 m: no side wall within 4 m for seven scans), and keeps it: its heading against
    the truth's is +0.69 degrees higher over scans 1800-1840 than over 1770-1792 (measured;
    +0.66 over the 191 drifted runs, SD 0.08 a step there). The outward pass crosses the same
    open area (scans 1398-1404) without it (+0.03). The corridor's walls say the truth is
    right: their direction in the world by the truth's poses is the same before and after
    (-4.04 and -3.97 degrees), where the front end's turns with it."""
    from dataclasses import replace

    from importers.carmen import Carmen, CarmenOptions
    from toolkit.poses import PoseStream
    from toolkit.slam.scanmap import MapConfig, scan_to_map

    path = real / "carmen_radish_corrected" / "infinite-corridor-corrected.log.gz"
    full = Carmen().read([path], CarmenOptions(poses="groundtruth", equal_poses="laser"))
    truth = truth_poses(full)
    assert truth is not None

    def offset(lo: int, hi: int) -> np.ndarray:
        """The front end on scans lo..hi-1, the truth its odometry: its heading minus the
        truth's (degrees), from 0 at the first scan."""
        part = slice(lo, hi)
        ds = replace(
            full,
            t=full.t[part],
            ranges=full.ranges[part],
            odometry=PoseStream(full.t[part], truth[part]),
            groundtruth=PoseStream(full.t[part], truth[part]),
            lasers={},
            poses={},
        )
        heading = scan_to_map(ds, MapConfig()).poses[:, 2]
        out = np.rad2deg(np.unwrap(heading) - np.unwrap(truth[part, 2]))
        result: np.ndarray = out - out[0]
        return result

    back = offset(1755, 1850)
    jump_back = back[1800 - 1755 : 1841 - 1755].mean() - back[1770 - 1755 : 1793 - 1755].mean()
    assert 0.4 < jump_back < 1.0, jump_back
    # the step into the open area holds most of it
    assert back[1793 - 1755] - back[1792 - 1755] > 0.4
    out = offset(1360, 1440)
    jump_out = out[1405 - 1360 : 1421 - 1360].mean() - out[1384 - 1360 : 1398 - 1360].mean()
    assert abs(jump_out) < 0.3, jump_out

    # the walls' direction by the truth: the same on both sides of the open area
    def walls(lo: int, hi: int) -> float:
        # scans along the corridor, either way (heading within 14 degrees of its axis)
        along = [k for k in range(lo, hi) if abs(np.cos(truth[k, 2])) > 0.97]
        return float(np.nanmean([_wall_direction(full, k, float(truth[k, 2])) for k in along]))

    before, after = walls(1765, 1793), walls(1800, 1841)
    assert -4.5 < before < -3.5 and -4.5 < after < -3.5
    assert abs(after - before) < 0.3, (before, after)
