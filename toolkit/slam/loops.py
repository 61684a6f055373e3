"""Loop closure: candidates from the trajectory so far, verified by a seed-free match.

Candidates: every `every` metres of path, the keyframe is compared with the earlier
keyframes more than `gap` metres back along the path; the nearest one within the trajectory's
uncertainty (`radius` + `growth` per metre of path between them, at most `window`) is a
candidate. Verification: a local map around the earlier keyframe (its neighbours within
`reference_path` m of path, placed by the trajectory, which is locally right) as likelihood
grids, and the later keyframe's local scans (within `query_path` m) matched against it by a
coarse-to-fine correlative search over the whole window (`toolkit.slam.grid`): no seed needed.
The fitness test: enough of the query's points close to the map (`min_inliers`), counted among
those a reference scan could have seen (`seen_only`: a revisit the other way sees behind it
what the reference never looked at; `line_of_sight`: nor behind the reference's walls), and a
clear winner: the best pose elsewhere in the window (0.6 m or 0.15 rad away) scores at most
`max_ambiguity` of the winner, among those seen points (`seen_ambiguity`; a corridor, where a
shift along it scores alike, fails it). A match that fails only that test, and whose
alike poses lie along one axis with none across it (`corridor_axis`), is kept as a corridor
loop: trusted across the axis and in heading only (`Loop.covariance`), its axis the ridge of
the fine score where the match put it (`corridor_ridge`). A loop is in the earlier
keyframe's frame, and a front-end slip there passes into it: it is refused when that scan fits
the rest of its local map, or the query fits that scan alone, 0.3 m from where the trajectory
put it (`anchor`, `anchor_match`); a corridor loop, trusted in heading, is refused when
scan a agrees poorly with the rest of its local map (`anchor_agree`), and withdrawn when the
optimum puts scan b metres along its axis from the match (`corridor_slide`: it matched another
stretch of the corridor; `corridor_rematch`: b matched again there). A winner on the search
window's edge is searched again from itself and refused when it moves (`edge_check`: the best
pose may lie beyond the window), and a loop on a scan a that fits its local map turned is
put in the frame of a neighbour of a that fits it (`reanchor`), or refused when none does
(`anchor_slip_turn`). Whether the loops agree
with each other is `toolkit.slam.consistency`'s test (`consistency_along`: a corridor loop's
spread along its axis there). The mapper runs these rounds with its own windows
(`toolkit.slam.pipeline`: a first round, smaller ones from the optimised trajectory, and a
last one up to `SlamConfig.wide_window` where no loop closed yet).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Container, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, replace
from typing import Any, TypeVar

import numba as nb
import numpy as np

from toolkit.dataset import LaserGeometry
from toolkit.se2 import between, compose, mount_pose, rotation, wrap
from toolkit.slam.grid import (
    _VOXEL_TABLE,
    CoarseLevel,
    LikelihoodGrid,
    SearchResult,
    _first_in_cell,
    _score,
    bounds,
    coarse_ambiguity,
    coarse_scores,
    coarse_search,
    fine_search,
    inside,
    voxel_subsample,
)


@dataclass(frozen=True)
class LoopConfig:
    """Loop closure parameters; lengths in m, angles in rad."""

    every: float = 2.0  # a query keyframe every this much path
    gap: float = 8.0  # candidates lie at least this far back along the path
    radius: float = 1.0  # position uncertainty at no path between (m) ...
    growth: float = 0.03  # ... plus this per metre of path between them
    window: float = 3.0  # ... at most (the search window, +-; the mapper's rounds set their own)
    turn: float = 0.35  # heading window (+-)
    query_path: float = 1.0  # query: scans within this path distance of the keyframe
    reference_path: float = 4.0  # reference map: keyframes within this path distance
    max_range: float = 25.0  # returns beyond this are left out of loop matching
    coarse: float = 0.2  # coarse grid cell and translation step (m)
    coarse_sigma: float = 0.25
    fine: float = 0.04  # fine grid cell and step (m)
    fine_sigma: float = 0.08
    turn_step: float = 0.02  # heading step of the coarse search
    query_voxel: float = 0.1  # query points: one per cell of this size
    coarse_voxel: float = 0.25  # ... and at the coarse level
    max_points: int = 400
    min_inliers: float = 0.65  # share of query points within 0.1 m of the map
    max_ambiguity: float = 0.85  # runner-up / winner of the coarse search
    min_points: int = 60  # fewer query points: no test
    seen_only: bool = True  # inliers among the query points the reference's scans could see
    # True: "could see" is along a beam's line of sight (not behind the surface it hit, +0.1
    # m); False: anywhere within the field of view and `max_range`. With `seen_ambiguity`, the
    # ambiguity test on the seen query points too (the others can confirm neither the winner
    # nor a runner-up). Both off by default: they close orebro's return (ATE 0.32 -> 0.15 m)
    # but accept more of freiburg-campus's marginal false loops (docs/journal/maps.md, session 12);
    # with the anchor tests below those are refused, but infinite-corridor loses (session 13)
    line_of_sight: bool = False
    seen_ambiguity: bool = False
    # a match ambiguous only along one axis (a corridor: its coarse scores as high along a line,
    # and low across it and at other headings) is kept as a corridor loop, trusted across the
    # axis and in heading only (`Loop.covariance`); False: rejected as ambiguous
    corridor: bool = True
    corridor_along: float = 100.0  # a corridor loop's spread along its axis (m): no pull there
    # a loop is in scan a's frame: a front-end slip there (scan a placed off its neighbours,
    # or keyframes of a's local map off each other) is carried into the loop, and the loops
    # nearby that share the local map carry it too, so they agree (docs/journal/maps.md,
    # session 13).
    # `anchor`: scan a matched against the rest of its local map; `anchor_match`: the query
    # matched against scan a alone, from the loop's pose; either fit `anchor_slip` m away
    # (across a corridor loop's axis), with `anchor_inliers` of its points within 0.1 m, is a
    # slip: the loop is refused
    anchor: bool = True
    anchor_match: bool = True
    anchor_slip: float = 0.3
    anchor_inliers: float = 0.3
    anchor_window: float = 1.0  # their search's window (m, +-) ...
    anchor_turn: float = 0.1  # ... and heading window (rad, +-)
    # `anchor`'s fit turned more than this (rad) from where the trajectory put scan a is a
    # heading slip, which a loop in a's frame carries whole (freiburg-campus seed 73's full loop
    # 216 -> 1161, 3.0 deg off the truth: scan 216 alone 3.5 deg off its neighbours, its fit
    # 3.1 deg turned but only 0.22 m moved, under `anchor_slip`; docs/journal/maps.md,
    # session 30); 0: off
    anchor_slip_turn: float = 0.05
    # True: a loop `anchor_slip_turn` refuses is instead put in the frame of the keyframe of
    # a's local map nearest a (by path) that fits that map itself (`anchor`'s fit within
    # `anchor_slip` and `anchor_slip_turn`, `anchor_agree` of its returns): the match is
    # against the whole local map, so only a's frame carries a's slip (freiburg-campus seeds
    # 73 / 135's 216 -> 1161, 0.49-0.50 m / 2.5-3.0 deg off the truth, re-anchored on 217
    # 0.03-0.05 m / 0.6-1.0 deg; seed 139's 245 -> 1253 3.5 -> 0.1 deg, whose refusal cost
    # 0.31 -> 0.43 m ATE); the loop then passes `anchor_agree` and `anchor_match` in that
    # keyframe's frame. On by default since session 31 (freiburg-campus seeds 0-160 and the
    # ten logs x seeds 0-40: it acts on 13 runs, every loop it keeps within 0.11 m and 2.2
    # deg of the truth, no false loop added; docs/journal/maps.md); False: refused
    reanchor: bool = True
    # a corridor loop is trusted in heading, and that heading is scan a's in its local map as
    # the trajectory placed it: refused when scan a fits its local map (`anchor`'s fit) with
    # fewer than this share of its returns (those the others could see) within 0.1 m (a scan
    # its neighbours do not agree with, as one taken in a fast turn, does not pin its heading:
    # fhw's 57 -> 370, 6-8 deg off, docs/journal/maps.md sessions 17-18). On by default since
    # session 18: on the spent held-out seeds 27-29 it refused 3 of their 4 false loops with
    # the ATE unchanged; 0: off (the default until then)
    anchor_agree: float = 0.75
    # in the consistency test only (the graph keeps `corridor_along`): a corridor loop's spread
    # along its axis (m), 0 for `corridor_along`. Two corridor loops whose axes lie a few
    # degrees apart leave a cycle free across too when each spreads 100 m along its own axis
    # (infinite-corridor seed 29 draw 0, 44 -> 768, 2.6 deg off, agrees with its neighbours
    # 1.5-3.2 deg apart); both take their along position from the same trajectory, so the
    # cycle's along error is the drift between them, metres at most. 2 m drops 44 -> 768 and
    # keeps the right 44 -> 756 with `anchor_agree` off; with it on (the default, which
    # refuses both) no false loop fewer on seeds 0-29, infinite-corridor moved both ways by
    # 0.002-0.08 m: off (docs/journal/maps.md, session 19)
    consistency_along: float = 0.0
    # a corridor loop's across offset and heading are those of the stretch of corridor where
    # the match put scan b, its along position the trajectory's then: when the optimum (pinned
    # along by full loops) puts b more than this many metres further along the axis, the match
    # compared b with another stretch, and a corridor 1-2 deg from straight over 12 m leaves
    # it 0.5 m across (infinite-corridor seed 33 draw 1's 42 -> 768, 12.8 m along, 1.6 deg):
    # withdrawn after optimising, as a residual is. With `corridor_rematch`, b is then matched
    # once more, from the optimum, against the earlier keyframe nearest where the optimum puts
    # it: the stretch b saw. On by default since session 21 (infinite-corridor seeds 0-35,
    # draws 0-1: false loops 2 -> 0, ATE paired mean -0.010 m; the other logs (nearly)
    # unchanged; docs/journal/maps.md); 0: off
    corridor_slide: float = 4.0
    corridor_rematch: bool = True
    # > 0 (m): a corridor loop's axis is the direction, within `ridge_turn` rad of the coarse
    # one (`corridor_axis`, from poses 0.2 m apart), along which the query slid +-this many m
    # from the winner keeps the highest mean fine score: the corridor's own axis to a fraction
    # of a degree. Along the axis the loop takes the trajectory's position, so an axis a few
    # degrees off the corridor's carries the across offset found at the winner, metres along,
    # wrong to there (infinite-corridor seed 23's 237 -> 497: winner 3.1 m along, coarse
    # axis 4.5 deg off the walls, 0.44 m across off the truth; on by default since session
    # 41: development seeds 0-24, accepted corridor loops over 0.2 m across off the truth
    # 26 -> 0, the 99th percentile 0.21 -> 0.09 m; docs/journal/maps.md); 0: the coarse axis
    corridor_ridge: float = 2.5
    ridge_turn: float = 0.14
    # a winner within this many metres of its search window's edge is the best pose the
    # window holds, and the best one may lie beyond it (a drift larger than the window): the
    # query is searched again centred on that winner (the same window and heading window), and
    # the loop refused when the new winner lies more than `anchor_slip` m from the first
    # (across a corridor loop's axis: along it the loop claims nothing). At a corridor's bend
    # the clipped ridge also tilts the corridor axis, so the across offset taken is wrong
    # (freiburg-campus seed 72's 241 -> 1252, 0.54 m off the truth, its true pose 0.8 m beyond
    # the window; docs/journal/maps.md, session 30); 0: off
    edge_check: float = 0.2
    # > 0 (m): a full loop is refused when one of its query's scans (scan b's within
    # `query_path`) lies, placed by the trajectory, more than this nearer to or farther from
    # scan b than the odometry has it (`LoopCloser.odometry`; none given: not tested): a
    # front-end slip along the path inside the query makes it a double image, which a
    # corridor-like place matches off along (freiburg-campus seed 1's 251 / 252 -> 1258: scan
    # 1259 0.39 m nearer 1258 than the odometry, which is 0.02 m off the truth there; the loops
    # 0.57 / 0.70 m off the truth). Distances, not positions: a wheel slip turns the odometry
    # (seed 45: 0.67 rad between 1260 and 1261, its scan 0.65 m off sideways) but changes its
    # distance by half the slip at most (0.16 m there). A corridor loop is not tested (its
    # along position is the trajectory's anyway). On by default since session 37: it acts on
    # seed 1 alone of freiburg-campus seeds 0-120, the nine other logs x seeds 0-40 and the
    # simulator's worlds 0-171 (false loops 2 -> 0, ATE 0.396 -> 0.352 m; every other run equal
    # to the bit; docs/journal/maps.md); the bench's odometry is the truth's with drift, so
    # where the truth is wrong it is too. 0: off
    query_odometry: float = 0.35
    # the fine level's winner moved to the parabola's top through its neighbours' scores
    # (`subcell`): loops nearer the truth (docs/journal/maps.md, session 42)
    subcell: bool = True
    # a full loop whose scan b, its own returns alone, fits a's local map more than this (m)
    # off the query's match (`LoopCloser.query_alone`: from that match over `anchor_window`)
    # is refused: one scan of the place fits elsewhere, so the match rests on where the
    # trajectory put the query's other scans, and a front-end slip among them moves it
    # (freiburg-campus's corridor at scans 1244-1260 against 237-253: drift seeds 1 and 562's
    # 252 -> 1258 / 1260, 0.66 / 0.51 m off the truth, scan b alone 0.23 / 0.24 m off the
    # match). Measured before `subcell`: freiburg-campus false loops 7 -> 4 in 220 runs (40
    # held out), none added in 384 runs of every log and the simulator, ATE within noise;
    # 2-7% more of the mapper's time (docs/journal/maps.md, session 42). 0: off
    query_alone: float = 0.2
    # loop candidates by appearance too (`toolkit.slam.recognition`: a Scan Context of each
    # keyframe's local map), not only by nearness on the trajectory: a round of its own after
    # the first (`toolkit.slam.pipeline`), for revisits the drift put beyond every window. On
    # by default since session 19: infinite-corridor seeds 5-14 x 2 draws mean ATE 1.21 ->
    # 0.38 m (worst 5.23 -> 0.51), no false loop on development seeds 0-14; False: off
    recognition: bool = True
    # > 0: a loop edge's covariance from its own match instead of `SlamConfig.loop_sigma`
    # (Olson 2009; Karto / slam_toolbox's `ComputePositionalCovariance` /
    # `ComputeAngularCovariance`): the query scored on the fine grid around the winner
    # (`response_covariance`: +-`response_window` m by `fine`, and headings +-`response_turn`
    # rad by `response_turn_step` at the winner's position), the response-weighted second
    # moments of the poses scoring within `response_drop` of the best, over the best score
    # (Karto's), times this squared, plus `response_floor` (m, rad) squared; a corridor loop
    # still spreads `corridor_along` along its axis. 0: off (every loop `loop_sigma`)
    response_scale: float = 0.0
    response_window: float = 0.2
    response_turn: float = 0.05
    response_turn_step: float = 0.005
    response_drop: float = 0.1
    response_floor: tuple[float, float] = (0.02, 0.002)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class Loop:
    """A verified (or rejected) loop: pose of keyframe `b`'s scan in keyframe `a`'s frame."""

    a: int  # scan index, earlier
    b: int  # scan index, later
    pose: np.ndarray
    score: float
    inliers: float
    ambiguity: float
    accepted: bool
    fit: bool = True  # passed the fitness test (`accepted` may still be withdrawn later)
    reason: str = ""  # why it is not accepted: fitness, consistency or the graph's residual
    axis: np.ndarray | None = None  # a corridor loop: unit vector (a's frame) it leaves free
    along: float = 0.0  # ... and its spread along that axis (m)
    recognised: bool = False  # proposed by appearance (`toolkit.slam.recognition`)
    anchored: int = -1  # `reanchor`: the scan a the match was made on (`a` a neighbour of it)
    # `LoopConfig.response_scale`: the edge's covariance from the match (b's frame, GTSAM's
    # tangent order, scaled and floored), instead of the mapper's fixed `loop_sigma`
    spread: np.ndarray | None = None

    def covariance(self, sigma: tuple[float, float], along: float = 0.0) -> np.ndarray:
        """The loop edge's covariance (GTSAM's tangent order, in `b`'s frame): `sigma`
        (m, rad) in every direction, or for a corridor loop `along` m along its axis (the
        argument, when > 0, instead of the loop's own); with `spread` (the match's own,
        `LoopConfig.response_scale`) that instead of `sigma`, the corridor's spread added
        along its axis."""
        u = self.free_axis()
        spread = along if along > 0 else self.along
        if self.spread is not None:
            own = self.spread.copy()
            if u is not None:  # the match's spread along the axis, at least `spread`
                own[:2, :2] += max(spread**2 - float(u @ own[:2, :2] @ u), 0.0) * np.outer(u, u)
            return own
        cov = np.diag([sigma[0] ** 2, sigma[0] ** 2, sigma[1] ** 2])
        if u is not None:
            cov[:2, :2] += (max(spread, sigma[0]) ** 2 - sigma[0] ** 2) * np.outer(u, u)
        return cov

    @property
    def pair(self) -> tuple[int, int]:
        """The candidate pair verified (scan a's, before any `reanchor`; then b)."""
        return (self.anchored if self.anchored >= 0 else self.a), self.b

    def free_axis(self) -> np.ndarray | None:
        """A corridor loop's axis in `b`'s frame (the edge's), None for a full loop."""
        if self.axis is None:
            return None
        c, s = np.cos(self.pose[2]), np.sin(self.pose[2])
        return np.array([c * self.axis[0] + s * self.axis[1], -s * self.axis[0] + c * self.axis[1]])


def path_length(poses: np.ndarray) -> np.ndarray:
    """Distance along the path at every pose (S,)."""
    step = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    return np.concatenate([[0.0], np.cumsum(step)])


class KeyIndex:
    """The keyframes' positions hashed into square cells of the search window's size, so that
    a query's candidates are looked up among the keyframes of the 3 x 3 cells around it
    instead of every earlier keyframe: the candidate search no longer grows with the square
    of the log's length (a 1,000,000-scan log has some 100,000 keyframes)."""

    def __init__(
        self, keys: np.ndarray, poses: np.ndarray, along: np.ndarray, config: LoopConfig
    ) -> None:
        self.config = config
        self.kp = poses[keys, :2]
        self.ka = along[keys]
        self.keys = keys
        self.cell = max(config.window, config.radius, 1e-3)
        ij = np.floor(self.kp / self.cell).astype(np.int64)
        order = np.lexsort((np.arange(len(keys)), ij[:, 1], ij[:, 0]))
        cells, first = np.unique(ij[order], axis=0, return_index=True)
        groups = np.split(order, first[1:])
        self.members = {(int(c[0]), int(c[1])): g for c, g in zip(cells, groups, strict=True)}
        self._ij = ij

    def candidate(self, q: int) -> tuple[int, int, float] | None:
        """The candidate of key number `q` (earlier scan, its scan, search radius), or None:
        the nearest earlier keyframe more than `gap` back along the path within the
        uncertainty (`radius` + `growth` per metre of path between, at most `window`)."""
        cfg = self.config
        ci, cj = self._ij[q]
        near = [
            g
            for di in (-1, 0, 1)
            for dj in (-1, 0, 1)
            if (g := self.members.get((int(ci + di), int(cj + dj)))) is not None
        ]
        if not near:
            return None
        idx = np.sort(np.concatenate(near))
        idx = idx[self.ka[q] - self.ka[idx] > cfg.gap]
        if len(idx) == 0:
            return None
        d = np.hypot(*(self.kp[idx] - self.kp[q]).T)
        reach = np.minimum(cfg.radius + cfg.growth * (self.ka[q] - self.ka[idx]), cfg.window)
        ok = np.nonzero(d < reach)[0]
        if len(ok) == 0:
            return None
        best = ok[np.argmin(d[ok])]
        return int(self.keys[idx[best]]), int(self.keys[q]), float(reach[best])


def candidates(
    keys: np.ndarray,
    poses: np.ndarray,
    along: np.ndarray,
    config: LoopConfig,
    skip: np.ndarray | None = None,
) -> list[tuple[int, int, float]]:
    """(earlier key, later key, search radius) pairs, as scan indices, a query every
    `config.every` of path that has a candidate; no query within `config.every` of path of a
    scan in `skip` (already closed)."""
    ka = along[keys]
    closed = np.sort(along[skip]) if skip is not None and len(skip) else np.zeros(0)
    index = KeyIndex(keys, poses, along, config)
    out: list[tuple[int, int, float]] = []
    next_at = 0.0
    for q in range(len(keys)):
        if ka[q] < next_at:
            continue
        if len(closed):
            at = np.searchsorted(closed, ka[q])
            near = closed[max(at - 1, 0) : at + 1]
            if (np.abs(near - ka[q]) < config.every).any():
                continue
        found = index.candidate(q)
        if found is not None:
            out.append(found)
            next_at = ka[q] + config.every
    return out


def query_scans(b: int, along: np.ndarray, config: LoopConfig) -> np.ndarray:
    """The scans of scan `b`'s query (within `query_path` m of path of it, at most 8 or so of
    them, evenly kept): what `LoopCloser.pair_points` matches for b."""
    near_b = np.nonzero(np.abs(along - along[b]) <= config.query_path)[0]
    out: np.ndarray = near_b[:: max(1, len(near_b) // 8)]  # a few scans are enough
    return out


def _capped(points: np.ndarray, config: LoopConfig) -> np.ndarray | None:
    """At most `max_points` of `points`, evenly kept in their order; None when fewer than
    `min_points` (too few to test a match by)."""
    if len(points) < config.min_points:
        return None
    if len(points) > config.max_points:
        points = points[np.linspace(0, len(points) - 1, config.max_points).astype(np.int64)]
    return points


@dataclass
class Staged:
    """A loop search stopped after its coarse level (`_coarse`): the level, its coarse grid,
    the reference points within reach (what the fine level needs) and, once asked, the
    corridor test's answer on it (`LoopCloser.coarse_refusal`)."""

    level: CoarseLevel
    grid: LikelihoodGrid
    ref: np.ndarray
    config: LoopConfig
    axis: np.ndarray | None = None
    axis_known: bool = False


def _coarse(
    ref: np.ndarray,
    query: np.ndarray,
    pose: np.ndarray,
    window: float,
    turn: float,
    config: LoopConfig,
) -> Staged | None:
    """`_search`'s coarse level: None when fewer than `min_points` reference points are within
    reach of `query` placed at `pose`."""
    cfg = config
    c, sn = np.cos(pose[2]), np.sin(pose[2])
    landed = pose[:2] + query @ np.array([[c, sn], [-sn, c]])
    reach = np.hypot(*query.T).max() * turn + window + 0.5
    lo, hi = bounds(landed)
    lo, hi = lo - reach, hi + reach
    ref = inside(ref, lo, hi)
    if len(ref) < cfg.min_points:
        return None
    coarse = LikelihoodGrid.build(ref, cfg.coarse, cfg.coarse_sigma, margin=1.0)
    level = coarse_search(
        coarse, query, pose, window, turn, cfg.turn_step, coarse_voxel=cfg.coarse_voxel
    )
    return Staged(level, coarse, ref, cfg)


def _fine(staged: Staged) -> tuple[SearchResult, LikelihoodGrid, LikelihoodGrid]:
    """`_search`'s fine level from its coarse level `staged`."""
    cfg, ref = staged.config, staged.ref
    grids: list[LikelihoodGrid] = []

    def fine_over(box_lo: np.ndarray, box_hi: np.ndarray) -> LikelihoodGrid:
        grids.append(
            LikelihoodGrid.window(ref, cfg.fine, cfg.fine_sigma, box_lo, box_hi, margin=0.5)
        )
        return grids[-1]

    found = fine_search(staged.level, fine_over, fine_resolution=cfg.fine)
    if cfg.subcell:
        level = staged.level
        found = replace(found, pose=subcell(grids[0], level.points, found.pose, level.turn_step))
    return found, staged.grid, grids[0]


def subcell(
    fine: LikelihoodGrid, query: np.ndarray, pose: np.ndarray, turn_step: float
) -> np.ndarray:
    """`pose` (the fine level's winner: a cell and one of its 7 headings) moved, in x, y and
    heading each, to the top of the parabola through the query's scores on `fine` one step
    either side (a cell; a third of `turn_step`), at most half a step: the search's steps (4 cm,
    0.38 deg) are coarser than a loop's heading needs."""
    out = pose.copy()
    here = fine.score(query, pose)
    for axis, step in enumerate((fine.resolution, fine.resolution, turn_step / 3)):
        side = np.zeros(3)
        side[axis] = step
        below, above = fine.score(query, pose - side), fine.score(query, pose + side)
        bend = below - 2.0 * here + above
        if bend < 0.0:
            out[axis] += float(np.clip(0.5 * (below - above) / bend, -0.5, 0.5)) * step
    return out


def _search(
    ref: np.ndarray,
    query: np.ndarray,
    pose: np.ndarray,
    window: float,
    turn: float,
    config: LoopConfig,
) -> tuple[SearchResult, LikelihoodGrid, LikelihoodGrid] | None:
    """`query` matched against `ref` (the reference points within reach of the query placed at
    `pose`) by the coarse-to-fine correlative search over +-`window` m, +-`turn` rad: the
    result, the coarse grid and the first fine grid; None when fewer than `min_points`
    reference points are within reach (`_coarse`, then `_fine`: `correlative_search`'s two
    levels)."""
    staged = _coarse(ref, query, pose, window, turn, config)
    return None if staged is None else _fine(staged)


@nb.njit(cache=True, nogil=True)
def _placed_returns(
    ranges: np.ndarray,
    cos_b: np.ndarray,
    sin_b: np.ndarray,
    mount: np.ndarray,
    max_range: float,
    rel: np.ndarray,
    cos_r: np.ndarray,
    sin_r: np.ndarray,
    out: np.ndarray,
) -> int:
    """`LoopCloser.local_points`'s returns in one pass: scan k's (S x B `ranges`, beam directions
    `cos_b`, `sin_b` with the mount's yaw) finite returns within `max_range` of the robot,
    placed at `rel[k]` (its heading's cos and sin given: numpy's, as before) into `out`,
    scan by scan in beam order, with the numpy form's arithmetic (a dozen temporaries of
    S x B per call before); returns how many."""
    m = 0
    for k in range(ranges.shape[0]):
        c, s = cos_r[k], sin_r[k]
        for i in range(ranges.shape[1]):
            r = np.float64(ranges[k, i])
            x = mount[0] + r * cos_b[i]
            y = mount[1] + r * sin_b[i]
            if np.isfinite(r) and math.hypot(x, y) <= max_range:
                out[m, 0] = rel[k, 0] + c * x - s * y
                out[m, 1] = rel[k, 1] + s * x + c * y
                m += 1
    return m


@nb.njit(cache=True, nogil=True)
def _placed_voxelled(
    ranges: np.ndarray,
    sizes: np.ndarray,
    cos_b: np.ndarray,
    sin_b: np.ndarray,
    mount: np.ndarray,
    max_range: float,
    rel: np.ndarray,
    cos_r: np.ndarray,
    sin_r: np.ndarray,
    voxel: float,
    most: int,
    out: np.ndarray,
    counts: np.ndarray,
) -> int:
    """Many `local_points` then `voxel_subsample` in one call: the scans (rows of `ranges`,
    `rel`, `cos_r`, `sin_r`) come in groups of `sizes`, each group's returns placed as
    `_placed_returns` places them, then the first point of each `voxel` cell kept
    (`_first_in_cell`); the groups' points one after the other into `out`, how many into
    `counts` (-1 where the cells were too many for the table: the caller does that group
    the plain way). Returns the points written."""
    m = 0
    row = 0
    for g in range(sizes.shape[0]):
        n = _placed_returns(
            ranges[row : row + sizes[g]],
            cos_b,
            sin_b,
            mount,
            max_range,
            rel[row : row + sizes[g]],
            cos_r[row : row + sizes[g]],
            sin_r[row : row + sizes[g]],
            out[m:],
        )
        row += sizes[g]
        if n == 0:
            counts[g] = 0
            continue
        keep = _first_in_cell(out[m : m + n], voxel, most)
        if keep is None:
            counts[g] = -1
            continue
        k = 0
        for i in range(n):
            if keep[i]:
                out[m + k, 0] = out[m + i, 0]
                out[m + k, 1] = out[m + i, 1]
                k += 1
        counts[g] = k
        m += k
    return m


_T = TypeVar("_T")


def _usable_cpus() -> int:
    affinity = getattr(os, "sched_getaffinity", None)
    return len(affinity(0)) if affinity is not None else os.cpu_count() or 1


#: threads that verify a round's candidates side by side (the CPUs this process may use, at
#: most 4); 1: one after the other. The loops found are the same either way.
WORKERS = min(_usable_cpus(), 4)


class LoopCloser:
    """Finds and verifies loops over a log's scans (S x B ranges; the returns of the few
    scans a test needs are computed when it needs them, so memory does not grow with S)."""

    # a pair the coarse level alone refuses is not searched at the fine level
    # (`coarse_refusal`; the same verdict, its Loop the coarse winner's); False: every
    # verification in full, as before session 26 (what the shortcut is checked against)
    refuse_at_coarse: bool = True

    def __init__(
        self,
        ranges: np.ndarray,
        laser: LaserGeometry,
        config: LoopConfig | None = None,
        odometry: np.ndarray | None = None,
    ) -> None:
        self.config = config or LoopConfig()
        self.ranges = ranges
        # the wheels' poses (S x 3), for `LoopConfig.query_odometry`; None: that test is off
        self.odometry = odometry
        mount = mount_pose(laser)
        self._mount = mount
        self._cos = np.cos(laser.angles + mount[2])
        self._sin = np.sin(laser.angles + mount[2])
        self._fov = (float(laser.angles.min()), float(laser.angles.max()))
        self._beam0, self._step = float(laser.angles[0]), float(laser.angle_increment)
        self._anchor_fits: dict[int, tuple[float, float, float]] = {}
        self.workers = WORKERS

    def local_points(self, centre: int, scans: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """The returns of `scans` (within `max_range` of the robot) in the frame of scan
        `centre`, scan by scan in beam order (`_placed_returns`)."""
        rel = between(np.broadcast_to(poses[centre], (len(scans), 3)), poses[scans])
        r = np.ascontiguousarray(self.ranges[scans])
        c, s = np.cos(rel[:, 2:3]).ravel(), np.sin(rel[:, 2:3]).ravel()  # as the numpy form's
        out = np.empty((r.size, 2))
        n = _placed_returns(
            r, self._cos, self._sin, self._mount, self.config.max_range, rel, c, s, out
        )
        return out[:n]

    def voxelled_maps(
        self, centres: np.ndarray, groups: list[np.ndarray], poses: np.ndarray, voxel: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per centre scan, `voxel_subsample(local_points(centre, group, poses), voxel)` (the
        same points): all groups' points one after the other, and how many each has. One
        numba call for them all instead of two per group (a recognition round describes
        every keyframe's local map)."""
        sizes = np.array([len(g) for g in groups], dtype=np.int64)
        scans = np.concatenate([*groups, np.zeros(0, dtype=np.int64)]).astype(np.int64)
        # every group's scans seen from its centre in one call (numpy's elementwise
        # arithmetic: each row as `local_points` computes it, to the bit; a call per group
        # was half of this function's time), and their headings' cos and sin likewise
        centre_of = np.repeat(np.asarray(centres, dtype=np.int64), sizes)
        rel = between(poses[centre_of], poses[scans])
        cos_r, sin_r = np.cos(rel[:, 2]), np.sin(rel[:, 2])
        r = np.ascontiguousarray(self.ranges[scans])
        out = np.empty((r.size, 2))
        counts = np.zeros(len(groups), dtype=np.int64)
        m = _placed_voxelled(
            r, sizes, self._cos, self._sin, self._mount, self.config.max_range, rel, cos_r,
            sin_r, voxel, _VOXEL_TABLE, out, counts,
        )  # fmt: skip
        points = out[:m]
        if (counts < 0).any():  # a group the table could not hold: the plain way
            parts = np.split(points, np.cumsum(np.maximum(counts, 0))[:-1])
            for k in np.nonzero(counts < 0)[0]:
                parts[k] = voxel_subsample(self.local_points(centres[k], groups[k], poses), voxel)
                counts[k] = len(parts[k])
            points = np.concatenate(parts)
        return points, counts

    def reference_keys(
        self, a: int, along: np.ndarray, keys: np.ndarray, config: LoopConfig | None = None
    ) -> np.ndarray:
        """The keyframes of scan `a`'s local map (within `reference_path` m of path of it):
        what a candidate's query is matched against (`_local` gives their returns)."""
        cfg = config or self.config
        near: np.ndarray = keys[np.abs(along[keys] - along[a]) <= cfg.reference_path]
        return near

    def pair_points(
        self,
        a: int,
        b: int,
        poses: np.ndarray,
        along: np.ndarray,
        keys: np.ndarray,
        config: LoopConfig | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """What `verify` matches for the pair (a, b): the query (scan `b`'s local scans'
        returns, voxelled and capped, b's frame), the keyframes of `a`'s local map and their
        returns (a's frame); None when the query has too few points."""
        cfg = config or self.config
        near_b = query_scans(b, along, cfg)
        query = _capped(voxel_subsample(self.local_points(b, near_b, poses), cfg.query_voxel), cfg)
        if query is None:
            return None
        near_a = self.reference_keys(a, along, keys, cfg)
        return query, near_a, self.local_points(a, near_a, poses)

    def verify(
        self,
        a: int,
        b: int,
        radius: float,
        poses: np.ndarray,
        along: np.ndarray,
        keys: np.ndarray,
        config: LoopConfig | None = None,
        prediction: np.ndarray | None = None,
        points: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> Loop | None:
        """Match scan `b`'s local scans against scan `a`'s local map over the window
        (`config`: a round's own, default the closer's) around `prediction` (b's pose in a's
        frame; default the trajectory's). `points`: the pair's `pair_points` (the same
        `poses`, `along`, `keys` and `config`), when the pair is verified more than once."""
        cfg = config or self.config
        if points is None:
            got = self.pair_points(a, b, poses, along, keys, cfg)
            if got is None:
                return None
            points = got
        if prediction is None:
            prediction = between(poses[a], poses[b])
        staged = self.search_coarse(radius, cfg, prediction, points)
        if staged is None:
            return None
        early = self.coarse_refusal(a, b, radius, prediction, points, staged)
        if early is not None:  # refused whatever the fine level finds: not searched
            return early
        searched = self.search_fine(staged)
        return self.judge(
            a, b, radius, poses, along, keys, cfg, prediction, points, searched, staged
        )

    def search_coarse(
        self,
        radius: float,
        config: LoopConfig,
        prediction: np.ndarray,
        points: tuple[np.ndarray, np.ndarray, np.ndarray],
    ) -> Staged | None:
        """`search`'s coarse level alone (`_coarse`); `_fine` of it is `search`'s answer."""
        query, _, ref = points
        return _coarse(ref, query, prediction, radius, config.turn, config)

    def search_fine(self, staged: Staged) -> tuple[SearchResult, LikelihoodGrid, LikelihoodGrid]:
        """`search`'s fine level from its coarse level (`search_coarse`): `search`'s answer."""
        return _fine(staged)

    def coarse_refusal(
        self,
        a: int,
        b: int,
        radius: float,
        prediction: np.ndarray,
        points: tuple[np.ndarray, np.ndarray, np.ndarray],
        staged: Staged,
    ) -> Loop | None:
        """The refused Loop when the coarse level alone decides `judge`'s verdict, else None.
        `judge` refuses every match whose coarse ambiguity exceeds `max_ambiguity` unless the
        corridor test (`corridor_axis`, on the coarse grid alone) finds an axis: both are the
        coarse level's, so the fine level cannot change that verdict (not so with
        `seen_ambiguity`, whose ambiguity is of the points seen from the fine pose). The Loop
        is the coarse winner's (pose, coarse score; inliers NaN: not measured) and its reason
        says so; the axis found, if any, is kept in `staged` for `judge`."""
        cfg, level = staged.config, staged.level
        ambiguity = level.ambiguity
        if not self.refuse_at_coarse or cfg.seen_ambiguity or not ambiguity > cfg.max_ambiguity:
            return None
        if cfg.corridor:
            staged.axis = corridor_axis(staged.grid, points[0], prediction, radius, cfg)
            staged.axis_known = True
            if staged.axis is not None:
                return None
        why = f"ambiguity {ambiguity:.2f} > {cfg.max_ambiguity} (coarse level)"
        pose = level.winner()
        return Loop(a, b, pose, level.coarse_score, math.nan, ambiguity, False, False, why)

    def search(
        self,
        radius: float,
        config: LoopConfig,
        prediction: np.ndarray,
        points: tuple[np.ndarray, np.ndarray, np.ndarray],
    ) -> tuple[SearchResult, LikelihoodGrid, LikelihoodGrid] | None:
        """`verify`'s correlative search alone (its `_search`): a pair's score at a heading
        without the tests, which `judge` then runs on the result."""
        query, _, ref = points
        return _search(ref, query, prediction, radius, config.turn, config)

    def judge(
        self,
        a: int,
        b: int,
        radius: float,
        poses: np.ndarray,
        along: np.ndarray,
        keys: np.ndarray,
        config: LoopConfig,
        prediction: np.ndarray,
        points: tuple[np.ndarray, np.ndarray, np.ndarray],
        searched: tuple[SearchResult, LikelihoodGrid, LikelihoodGrid],
        staged: Staged | None = None,
    ) -> Loop:
        """`verify`'s tests (overlap, inliers, ambiguity, corridor, anchors) on the search
        `searched` of the pair (`search` with the same arguments): the Loop `verify` gives.
        `staged`: its coarse level, with the corridor test's answer if `coarse_refusal` ran it
        (the same call on the same grid: not run again)."""
        cfg = config
        query, near_a, _ = points
        found, coarse, fine = searched
        ambiguity = found.ambiguity
        inliers = found.inliers
        why = []
        if cfg.seen_only:
            seen = self.seen(query, found.pose, a, near_a, poses)
            near = fine.distances(query[seen], found.pose) <= 0.1
            inliers = float(near.mean()) if len(near) else 0.0
            if seen.sum() < cfg.min_points:
                why.append(f"overlap {int(seen.sum())} points < {cfg.min_points}")
            elif cfg.seen_ambiguity:  # the score surface of the seen points alone
                best, runner_up = coarse_ambiguity(
                    coarse,
                    voxel_subsample(query[seen], cfg.coarse_voxel),
                    prediction,
                    radius,
                    cfg.turn,
                    cfg.turn_step,
                )
                ambiguity = runner_up / max(best, 1e-9)
        if inliers < cfg.min_inliers:
            why.append(f"inliers {inliers:.2f} < {cfg.min_inliers}")
        pose, axis = found.pose, None
        if ambiguity > cfg.max_ambiguity:
            if not why and cfg.corridor:
                if staged is not None and staged.axis_known:
                    axis = staged.axis
                else:
                    axis = corridor_axis(coarse, query, prediction, radius, cfg)
            if axis is None:
                why.append(f"ambiguity {ambiguity:.2f} > {cfg.max_ambiguity}")
            else:  # along the axis the match says nothing: keep the trajectory's position
                pose = at_prediction(found.pose, prediction, axis)
        # the loop's frame: scan a's, or (`reanchor`) a neighbour's when a fits turned
        k, pose_k, won_k, axis_k = a, pose, found.pose, axis
        rel: np.ndarray | None = None  # a's pose in k's frame, when k is not a
        if not why and cfg.anchor:
            moved, agree, turned = self.anchor_fit(a, along, keys, poses, cfg)
            if moved > cfg.anchor_slip:
                why.append(f"anchor: scan {a} fits its local map {moved:.2f} m off")
            elif cfg.anchor_slip_turn > 0 and turned > cfg.anchor_slip_turn:
                steady = self.steady_neighbour(a, along, keys, poses, cfg) if cfg.reanchor else None
                if steady is None:
                    why.append(
                        f"anchor: scan {a} fits its local map {math.degrees(turned):.1f} deg turned"
                    )
                else:  # the same match, in n's frame (as the trajectory places a from n)
                    n, agree = steady
                    rel = between(poses[n], poses[a])
                    k, won_k = n, compose(rel, found.pose)
                    pose_k, axis_k = in_frame(rel, pose, axis)
            if not why and axis_k is not None and agree < cfg.anchor_agree:
                why.append(
                    f"anchor: scan {k} fits its local map with {agree:.2f} of its returns"
                    f" < {cfg.anchor_agree} (a corridor loop's heading)"
                )
        if not why and cfg.anchor_match:
            slip = self.anchor_shift(k, query, won_k, poses, cfg)
            if slip is not None and slip[1] >= cfg.anchor_inliers:
                shift = rotation(won_k[2]) @ slip[0][:2]  # k's frame
                if axis_k is not None:
                    shift -= (shift @ axis_k) * axis_k
                moved = float(np.hypot(*shift))
                if moved > cfg.anchor_slip:
                    why.append(f"anchor: scan {k} alone fits the query {moved:.2f} m off")
        if not why and cfg.query_odometry > 0 and axis is None and self.odometry is not None:
            off, s = self.query_slip(b, poses, along, cfg)
            if off > cfg.query_odometry:
                why.append(
                    f"query: scan {s} placed {off:.2f} m off the odometry's distance from {b}"
                )
        if not why and cfg.query_alone > 0 and axis is None:
            moved = self.query_alone(b, poses, ref=points[2], pose=found.pose, config=cfg)
            if moved > cfg.query_alone:
                why.append(f"query: scan {b} alone fits {moved:.2f} m off the query's match")
        if not why and cfg.edge_check > 0:
            moved = self.edge_move(radius, cfg, prediction, points, found.pose, axis)
            if moved > cfg.anchor_slip:
                why.append(
                    f"edge: searched again from its winner on the window's edge, {moved:.2f} m off"
                )
        ok = not why
        if ok and axis is not None and cfg.corridor_ridge > 0:  # the corridor's own axis
            axis = ridge_axis(points[2], query, found.pose, axis, cfg)
            pose = at_prediction(found.pose, prediction, axis)
            pose_k, axis_k = (pose, axis) if rel is None else in_frame(rel, pose, axis)
        loop = Loop(k, b, pose_k, found.score, inliers, ambiguity, ok, ok, "; ".join(why))
        if k != a:
            loop.anchored = a
        if ok and cfg.response_scale > 0:
            loop.spread = edge_spread(
                response_covariance(fine, query, found.pose, cfg), found.pose, cfg
            )
        if axis_k is not None:
            loop.axis, loop.along = axis_k, cfg.corridor_along
        return loop

    def query_slip(
        self, b: int, poses: np.ndarray, along: np.ndarray, config: LoopConfig
    ) -> tuple[float, int]:
        """How much nearer to or farther from scan `b` (m) the query's scans (`query_scans`)
        lie placed by `poses` than the odometry (`odometry`) has them: the most, and its scan."""
        assert self.odometry is not None
        near_b = query_scans(b, along, config)
        far_odo = np.hypot(*(self.odometry[near_b, :2] - self.odometry[b, :2]).T)
        far_placed = np.hypot(*(poses[near_b, :2] - poses[b, :2]).T)
        dist = np.abs(far_placed - far_odo)
        worst = int(np.argmax(dist))
        return float(dist[worst]), int(near_b[worst])

    def steady_neighbour(
        self, a: int, along: np.ndarray, keys: np.ndarray, poses: np.ndarray, config: LoopConfig
    ) -> tuple[int, float] | None:
        """The keyframe of scan `a`'s local map (`reference_keys`), a left out, nearest a by
        path (the earlier first on a tie) that fits its own local map where the trajectory
        put it (`anchor_fit`: within `anchor_slip` m and `anchor_slip_turn` rad, with
        `anchor_agree` of its returns), and that share; None when none does (`reanchor`).
        The fits it computes are not kept: where it finds none, every later test is the
        same as without it."""
        cfg = config
        refs = self.reference_keys(a, along, keys, cfg)
        refs = refs[refs != a]
        for n in refs[np.argsort(np.abs(along[refs] - along[a]), kind="stable")]:
            moved, agree, turned = self.anchor_fit(int(n), along, keys, poses, cfg, keep=False)
            ok = moved <= cfg.anchor_slip and turned <= cfg.anchor_slip_turn
            if ok and agree >= cfg.anchor_agree:
                return int(n), agree
        return None

    def edge_move(
        self,
        radius: float,
        config: LoopConfig,
        prediction: np.ndarray,
        points: tuple[np.ndarray, np.ndarray, np.ndarray],
        winner: np.ndarray,
        axis: np.ndarray | None,
    ) -> float:
        """How far (m; across `axis` when given, a's frame) the query's winner moves when
        searched again centred on `winner` over the same window (`radius`, `config.turn`): 0
        when `winner` lies more than `edge_check` m inside the window around `prediction`
        (the search saw all around it) or the second search finds too few reference points."""
        margin = radius - float(np.abs(winner[:2] - prediction[:2]).max())
        if margin >= config.edge_check:
            return 0.0
        again = self.search(radius, config, winner, points)
        if again is None:
            return 0.0
        shift = again[0].pose[:2] - winner[:2]
        if axis is not None:
            shift = shift - (shift @ axis) * axis
        return float(np.hypot(*shift))

    def anchor_shift(
        self, a: int, query: np.ndarray, pose: np.ndarray, poses: np.ndarray, config: LoopConfig
    ) -> tuple[np.ndarray, float] | None:
        """The query (b's frame) matched against scan `a`'s own returns alone, from `pose` (its
        match against a's local map) over a small window: the shift of that match from `pose`
        (in b's frame) and its inlier share; None when scan a sees too few of the query's
        points to tell. A local map holds a front-end slip (keyframes placed 0.5 m off their
        neighbours) that a match against it inherits; scan a alone holds none."""
        own = self.local_points(a, np.array([a]), poses)
        pts = query[self.seen(query, pose, a, np.array([a]), poses)]
        return self._refit(own, pts, pose, config)

    def query_alone(
        self, b: int, poses: np.ndarray, ref: np.ndarray, pose: np.ndarray, config: LoopConfig
    ) -> float:
        """How far (m, b's frame) scan `b`'s own returns alone fit `ref` (a's local map) from
        `pose` (the query's match there); 0 when too few to tell. Far: one scan of the place
        fits elsewhere, and the match rests on the trajectory's placement of the others."""
        own = voxel_subsample(self.local_points(b, np.array([b]), poses), config.query_voxel)
        got = self._refit(ref, own, pose, config)
        return 0.0 if got is None else float(np.hypot(got[0][0], got[0][1]))

    def anchor_fit(
        self,
        k: int,
        along: np.ndarray,
        keys: np.ndarray,
        poses: np.ndarray,
        config: LoopConfig,
        keep: bool = True,
    ) -> tuple[float, float, float]:
        """How far (m) keyframe `k` fits its local map off where the trajectory put it (0 when
        too few of its returns overlap the map or agree with it to tell), the share of its
        returns (those the map's scans could see) within 0.1 m of the map at that fit (1 when
        too few overlap to tell), and how far that fit turned it (|rad|, 0 when the distance
        is); kept per keyframe for the closer's life (the trajectory's rounds move a local map
        as a whole), unless `keep` is False (a fit computed then is not kept)."""
        if k in self._anchor_fits:
            return self._anchor_fits[k]
        found = self.anchor_consistency(
            k, self.reference_keys(k, along, keys, config), poses, config
        )
        ok = found is not None and found[1] >= config.anchor_inliers
        moved = float(np.hypot(*found[0][:2])) if found is not None and ok else 0.0
        turned = abs(float(wrap(found[0][2]))) if found is not None and ok else 0.0
        fit = (moved, 1.0 if found is None else float(found[1]), turned)
        if keep:
            self._anchor_fits[k] = fit
        return fit

    def anchor_consistency(
        self, a: int, refs: np.ndarray, poses: np.ndarray, config: LoopConfig
    ) -> tuple[np.ndarray, float] | None:
        """Scan `a`'s returns matched against the other scans of its local map `refs` (placed
        by the trajectory) over a small window: the shift of a's best fit from where the
        trajectory put it (a's frame) and its inlier share; None when too few overlap."""
        others = refs[refs != a]
        if len(others) == 0:
            return None
        own = voxel_subsample(self.local_points(a, np.array([a]), poses), config.query_voxel)
        zero = np.zeros(3)
        pts = own[self.seen(own, zero, a, others, poses)]
        return self._refit(self.local_points(a, others, poses), pts, zero, config)

    def _refit(
        self, ref: np.ndarray, pts: np.ndarray, pose: np.ndarray, config: LoopConfig
    ) -> tuple[np.ndarray, float] | None:
        """`pts` matched against `ref` by the correlative search from `pose` over
        `anchor_window` / `anchor_turn`: the found pose relative to `pose`, and the inliers."""
        capped = _capped(pts, config)
        if capped is None:
            return None
        searched = _search(ref, capped, pose, config.anchor_window, config.anchor_turn, config)
        if searched is None:
            return None
        return between(pose, searched[0].pose), searched[0].inliers

    def seen(
        self, query: np.ndarray, pose: np.ndarray, a: int, refs: np.ndarray, poses: np.ndarray
    ) -> np.ndarray:
        """Which `query` points (b's frame), placed at `pose` in scan `a`'s frame, lie where
        one of the reference scans `refs` could have seen them (within the laser's field of
        view and `max_range`, and with `line_of_sight` not behind the return of the beam that
        points there): a revisit in the opposite direction sees, behind it, what the
        reference never looked at, and a revisit from another side sees behind the reference's
        walls; those points can neither confirm nor contradict."""
        c, s = np.cos(pose[2]), np.sin(pose[2])
        pts = pose[:2] + query @ np.array([[c, s], [-s, c]])
        lasers = compose(
            between(np.broadcast_to(poses[a], (len(refs), 3)), poses[refs]),
            np.broadcast_to(self._mount, (len(refs), 3)),
        )
        dx = pts[:, None, 0] - lasers[None, :, 0]
        dy = pts[:, None, 1] - lasers[None, :, 1]
        bearing = wrap(np.arctan2(dy, dx) - lasers[None, :, 2])
        inside = (bearing >= self._fov[0]) & (bearing <= self._fov[1])
        reach = np.full(bearing.shape, self.config.max_range)
        if self.config.line_of_sight:
            # the farthest return of the beam and its two neighbours (a point between beams),
            # no return as `max_range`; a point up to the inlier distance behind it is seen
            r = self.ranges[refs].astype(np.float64)
            r = np.where(
                np.isfinite(r), np.minimum(r, self.config.max_range), self.config.max_range
            )
            pad = np.pad(r, ((0, 0), (1, 1)), mode="edge")
            far = np.maximum(np.maximum(pad[:, :-2], pad[:, 1:-1]), pad[:, 2:])
            beam = np.clip(np.rint((bearing - self._beam0) / self._step), 0, r.shape[1] - 1)
            reach = np.minimum(
                far[np.arange(len(refs))[None, :], beam.astype(np.int64)] + 0.1, reach
            )
        out: np.ndarray = (inside & (np.hypot(dx, dy) <= reach)).any(axis=1)
        return out

    def find(
        self,
        keys: np.ndarray,
        poses: np.ndarray,
        config: LoopConfig | None = None,
        skip: np.ndarray | None = None,
        known: Container[tuple[int, int]] = (),
    ) -> list[Loop]:
        """Every candidate of the trajectory `poses` (S x 3), verified; rejected ones too.
        Candidate pairs (a, b) in `known` (verified before) are not verified again."""
        cfg = config or self.config
        along = path_length(poses)
        todo = [c for c in candidates(keys, poses, along, cfg, skip) if c[:2] not in known]
        return self.each(lambda c: self.verify(*c, poses, along, keys, cfg), todo)

    def each(self, check: Callable[[_T], Loop | None], todo: Sequence[_T]) -> list[Loop]:
        """`check` of every item of `todo`, in order, the Nones left out: in `workers` threads
        (the searches are nogil numba kernels; a pair's verdict does not depend on the
        others', so the loops are the same whatever the threads)."""
        if self.workers <= 1 or len(todo) < 2:
            found = [check(t) for t in todo]
        else:
            with ThreadPoolExecutor(self.workers) as pool:
                found = list(pool.map(check, todo))
        return [lp for lp in found if lp is not None]


def response_covariance(
    fine: LikelihoodGrid, query: np.ndarray, pose: np.ndarray, config: LoopConfig
) -> np.ndarray:
    """The spread of the correlative search's responses around its winner `pose` (query `b`
    in a's frame; Karto's `ComputePositionalCovariance` / `ComputeAngularCovariance`): the
    query scored on the fine grid `fine` (`coarse_scores`) at the winner's heading over
    +-`response_window` m (the grid's step) and at the winner's position over +-`response_turn`
    rad (by `response_turn_step`); of the poses scoring within `response_drop` of the best,
    the response-weighted second moments of their offsets from the winner, over the best score
    (a weak match spreads more). 3 x 3 (x, y in a's frame, heading; no heading-position
    terms), unscaled and unfloored."""
    cfg = config
    centre = np.ascontiguousarray(pose, dtype=np.float64)
    plane, offsets, _ = coarse_scores(fine, query, centre, cfg.response_window, 0.0, 1.0)
    line, _, turns = coarse_scores(
        fine, query, centre, 0.0, cfg.response_turn, cfg.response_turn_step
    )
    plane, line = plane[0], line[:, 0, 0]  # (x, y) at the winner's heading; per heading
    best = max(float(plane.max()), float(line.max()), 1e-9)
    xy = np.stack([g.ravel() for g in np.meshgrid(offsets, offsets, indexing="ij")])
    w = np.where(plane >= best - cfg.response_drop, plane, 0.0).ravel()
    wt = np.where(line >= best - cfg.response_drop, line, 0.0)
    cov = np.zeros((3, 3))
    cov[:2, :2] = (xy * w) @ xy.T / max(float(w.sum()), 1e-12)
    cov[2, 2] = float(wt @ turns**2) / max(float(wt.sum()), 1e-12)
    return cov / best


def edge_spread(response: np.ndarray, pose: np.ndarray, config: LoopConfig) -> np.ndarray:
    """A loop edge's covariance from its match's `response_covariance` (a's frame) at `pose`:
    times `response_scale` squared, its position part turned into b's frame (the edge's,
    GTSAM's tangent order), plus `response_floor` (m, rad) squared in every direction."""
    cfg = config
    r = rotation(float(pose[2]))
    cov = response * cfg.response_scale**2
    cov[:2, :2] = r.T @ cov[:2, :2] @ r
    cov[:2, :2] += cfg.response_floor[0] ** 2 * np.eye(2)
    cov[2, 2] += cfg.response_floor[1] ** 2
    return cov


def corridor_axis(
    coarse: LikelihoodGrid,
    query: np.ndarray,
    prediction: np.ndarray,
    radius: float,
    config: LoopConfig,
    away: float = 0.6,
    away_turn: float = 0.15,
) -> np.ndarray | None:
    """The axis (unit vector, `a`'s frame) along which an ambiguous match is free, or None
    when it is not a corridor's: the coarse poses near the winner's heading that score within
    `max_ambiguity` of it lie along a line (their principal axis through the winner), and no
    pose `away` m across that line or `away_turn` rad off in heading does (another corridor
    alongside, or a turn, is a real ambiguity)."""
    pts = voxel_subsample(query, config.coarse_voxel)
    vol, offsets, thetas = coarse_scores(
        coarse, pts, prediction, radius, config.turn, config.turn_step
    )
    best = float(vol.max())
    if best <= 0:
        return None
    wa, wi, wj = np.unravel_index(int(np.argmax(vol)), vol.shape)
    dx, dy = np.meshgrid(offsets - offsets[wi], offsets - offsets[wj], indexing="ij")
    near_turn = np.abs(thetas - thetas[wa]) <= away_turn
    high = (vol >= config.max_ambiguity * best) & near_turn[:, None, None]
    _, hi, hj = np.nonzero(high)
    d = np.column_stack([dx[hi, hj], dy[hi, hj]])
    _, vec = np.linalg.eigh(d.T @ d)
    axis = vec[:, 1]
    if np.abs(d @ axis).max() <= away:  # no second mode along a line
        return None
    across = np.abs(dx * axis[1] - dy * axis[0])[None] > away
    far = across | ~near_turn[:, None, None]
    if far.any() and vol[far].max() > config.max_ambiguity * best:
        return None
    out: np.ndarray = axis
    return out


def at_prediction(winner: np.ndarray, prediction: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """A corridor match's `winner` moved along `axis` to `prediction`'s position along it
    (along the axis the match says nothing: the trajectory's position is kept)."""
    pose = winner.copy()
    pose[:2] -= ((pose[:2] - prediction[:2]) @ axis) * axis
    return pose


def in_frame(
    rel: np.ndarray, pose: np.ndarray, axis: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """A loop's `pose` and corridor `axis` (scan a's frame) in the frame of the scan from
    which a lies at `rel` (`reanchor`)."""
    return compose(rel, pose), None if axis is None else rotation(rel[2]) @ axis


RIDGE_STEPS = (11, math.radians(0.5))  # slides along a candidate axis; the candidates' spacing
RIDGE_NEAR = 8.0  # m: the query's points this near scan b tell the corridor there


def ridge_axis(
    ref: np.ndarray, query: np.ndarray, winner: np.ndarray, axis: np.ndarray, config: LoopConfig
) -> np.ndarray:
    """The direction within `ridge_turn` of `axis` along which `query` (b's frame; its points
    within `RIDGE_NEAR` of b) slid from `winner` (a's frame) over +-`corridor_ridge` m scores
    highest on the fine grid of `ref` (a's local map), summed over the slides: the ridge of
    a corridor's score surface. Run on a corridor loop that passed every test."""
    query = query[np.hypot(query[:, 0], query[:, 1]) <= RIDGE_NEAR]
    if len(query) < config.min_points:
        return axis
    reach = config.corridor_ridge + 1.0
    c, sn = np.cos(winner[2]), np.sin(winner[2])
    lo, hi = bounds(winner[:2] + query @ np.array([[c, sn], [-sn, c]]))
    near = inside(ref, lo - reach, hi + reach)
    if len(near) < config.min_points:
        return axis
    fine = LikelihoodGrid.build(near, config.fine, config.fine_sigma, margin=1.0)
    slides, spacing = RIDGE_STEPS
    half = int(config.ridge_turn / spacing)
    phis = np.arange(-half, half + 1) * spacing
    base = math.atan2(axis[1], axis[0])
    units = np.column_stack([np.cos(base + phis), np.sin(base + phis)])
    ts = np.linspace(-config.corridor_ridge, config.corridor_ridge, slides)
    scores = _ridge_scores(
        fine.likelihood,
        fine.origin,
        fine.resolution,
        np.ascontiguousarray(query),
        winner,
        units,
        ts,
    )
    out: np.ndarray = units[int(np.argmax(scores))]
    return out


@nb.njit(cache=True, nogil=True)
def _ridge_scores(
    like: np.ndarray,
    origin: np.ndarray,
    res: float,
    pts: np.ndarray,
    winner: np.ndarray,
    units: np.ndarray,
    ts: np.ndarray,
) -> np.ndarray:
    """Per direction in `units`, the summed mean likelihood of `pts` at `winner` slid by each
    of `ts` along it (`LikelihoodGrid.score` of each)."""
    out = np.zeros(units.shape[0])
    pose = np.empty(3)
    pose[2] = winner[2]
    for k in range(units.shape[0]):
        for t in ts:
            pose[0] = winner[0] + t * units[k, 0]
            pose[1] = winner[1] + t * units[k, 1]
            out[k] += _score(like, origin, res, pts, pose)
    return out


def loop_truth_error(loop: Loop, truth: np.ndarray) -> tuple[float, float]:
    """A loop's residual against the truth: translation (m) and |rotation| (deg); a corridor
    loop's translation across its axis only (along it the loop claims nothing)."""
    err = between(between(truth[loop.a], truth[loop.b]), loop.pose)
    u = loop.free_axis()
    if u is not None:
        err[:2] -= (err[:2] @ u) * u
    return float(np.hypot(err[0], err[1])), float(
        np.rad2deg(abs((err[2] + np.pi) % (2 * np.pi) - np.pi))
    )


FALSE_LOOP = (0.5, 5.0)  # m, deg: a loop further than this from the truth is false (#20)


def is_false_loop(loop: Loop, truth: np.ndarray) -> bool:
    """A loop whose residual against the truth exceeds `FALSE_LOOP` (`loop_truth_error`)."""
    t, r = loop_truth_error(loop, truth)
    return t > FALSE_LOOP[0] or r > FALSE_LOOP[1]


__all__ = [
    "KeyIndex",
    "Loop",
    "LoopCloser",
    "LoopConfig",
    "candidates",
    "compose",
    "corridor_axis",
    "is_false_loop",
    "loop_truth_error",
    "query_scans",
]
