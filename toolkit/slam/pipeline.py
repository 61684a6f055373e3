"""The default mapper: sequential matching, loop closure and the pose graph.

1. Sequential: every scan matched by the Gaussian scan matcher (`toolkit.align.scan`), seeded
   by odometry, or by constant velocity when the log has none (`toolkit.slam.localmap`).
2. Keyframes every `keyframe_distance` m or `keyframe_angle` rad of the estimate; the pose
   graph has one node per keyframe and a sequential edge between consecutive ones (the
   matcher's covariance, floored).
3. Loops: candidates from the trajectory, verified by a correlative search
   (`toolkit.slam.loops`); loops that the loops nearby contradict through the sequential
   chain between them, or that no loop nearby confirms, are dropped
   (`toolkit.slam.consistency`); each remaining loop is an edge with a Cauchy kernel. The
   graph is optimised (GTSAM; each optimisation from the last optimum, `warm_start`); loops
   that the optimum still contradicts (Mahalanobis distance beyond `reject_chi2`) are dropped
   and the graph optimised again. A second round searches again
   from the optimised trajectory, where the windows can be smaller; a last one, where no loop
   closed yet, with a window as wide as the drift along the path between (`wide_window`).
   With `LoopConfig.recognition`, a round after the first proposes candidates by appearance
   (`toolkit.slam.recognition`), where no loop closed yet, whatever the drift.
4. Every scan's pose: its keyframe's optimised pose composed with its sequential offset.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from toolkit import se2
from toolkit.align import scan as sc
from toolkit.dataset import Dataset, LaserGeometry
from toolkit.raster import world_points
from toolkit.slam import consistency, recognition
from toolkit.slam import graph as pg
from toolkit.slam.consistency import CHI2_3DOF_99
from toolkit.slam.loops import (
    KeyIndex,
    Loop,
    LoopCloser,
    LoopConfig,
    is_false_loop,
    loop_truth_error,
    path_length,
)
from toolkit.slam.scanmap import SEARCH_MIN, MapConfig, returns

if TYPE_CHECKING:
    import gtsam


@dataclass(frozen=True)
class SlamConfig:
    """The mapper's parameters (the sequential matcher's are `MatchConfig`'s)."""

    loops: bool = True
    keyframe_distance: float = 0.5
    keyframe_angle: float = 0.3
    sigma_floor: tuple[float, float] = (0.02, 0.005)  # m, rad: least spread of a sequential edge
    sigma_per_metre: tuple[float, float] = (0.02, 0.01)  # ... plus this per metre of the edge
    loop_sigma: tuple[float, float] = (0.05, 0.01)  # m, rad: a loop edge's spread
    # > 0: a sequential edge's covariance is the front end's own (each scan's (H/sigma^2 +
    # prior)^-1, summed over the edge's steps in its first scan's frame) times this squared,
    # plus `matcher_floor` (m, rad) squared, instead of `sigma_floor` + `sigma_per_metre`
    # (needs the steps' covariances: `close_loops(step_cov=...)`, the scan-to-map front end).
    # An expert setting, off: 3 was measured (development seeds, docs/journal/maps.md session
    # 20) better on freiburg-campus (mean ATE 0.336 -> 0.310 m over 30 runs), belgioioso and
    # orebro, the same elsewhere, but worse on infinite-corridor (0.392 -> 0.441 m: a chain
    # stiffer in heading places its one-pass stretches worse)
    matcher_cov: float = 0.0
    matcher_floor: tuple[float, float] = (0.01, 0.0025)
    robust: float = 1.0  # Cauchy kernel width, in sigmas
    reject_chi2: float = 16.0  # loops still this far off after optimising are dropped
    consistency_path: float = 10.0  # loops whose ends lie this close along the path are compared
    consistency_chi2: float = CHI2_3DOF_99  # ... and agree when their cycle is within this
    confirm: bool = True  # a loop that no loop nearby agrees with is dropped
    rounds: int = 2
    # a last round with a wide window: from the optimised trajectory, where no loop closed, the
    # window grows `wide_growth` per metre of path between the two poses up to `wide_window`
    # (0: no such round), so that a revisit the drift put beyond `loop.window` is searched
    # (freiburg-campus seed 0: the start's revisit 11-12 m off before loops; docs/maps.md)
    wide_window: float = 12.0
    wide_growth: float = 0.05
    wide_skip_corridors: bool = True  # the wide round leaves out corridor loops' queries
    incremental: bool = False  # re-optimise as soon as a loop moves its scan (round 1)
    # each optimisation starts from the last optimum (the loops a round adds or drops move it
    # little) instead of from the sequential estimate: fewer Levenberg-Marquardt iterations
    warm_start: bool = True
    # an optimisation that leaves a loop beyond `reject_chi2` is run again from GTSAM's LAGO
    # start (`graph.lago_start`: the orientations solved linearly over the whole graph, turns
    # of any size) and that optimum kept if the graph's error there is under this share of the
    # warm start's (0: off). Levenberg-Marquardt from the last optimum can settle with a
    # stretch turned a quarter round after a round of loops that turn the trajectory far: the
    # million-scan laps (bench_loops_scale), after the appearance round, 5,669 scans 90 deg
    # off (graph error 288 against LAGO's 106), then held there by loops at the building's 90
    # deg alias (10 false loops, ATE 1.80 m; docs/journal/maps.md, session 43)
    lago_restart: float = 0.9
    local_map: int = 4  # keyframe front end: each keyframe is also matched against this many
    # earlier ones (0: none); the scan-to-map front end has its own local map
    min_agreement: float = 0.5  # a local-map match with fewer agreeing returns is left out
    # > 0: a local-map edge's heading spread (rad) instead of the floor and per-metre one: its
    # translation kept, its heading left to the sequential edges. An expert setting, off; 1
    # with `MatchConfig.heading_map` (the keyframes' headings fitted to a local map): the
    # lags' pair matches repeat the drift the map took out (the CCNY hand-held bag: 1,223
    # cells of 5 cm with them, 1,069 without). On the simulator without odometry the lags'
    # heading is worth 0.05 m ATE on the corridor (docs/journal/maps.md, session 27)
    local_map_turn: float = 0.0
    # True: the scan-to-map front end gets the local-map edges too (each keyframe matched to
    # the 2nd .. `local_map`-th before it). An expert setting, off: over the ten real logs x
    # drift seeds 0-9 the same on the whole (mean ATE 0.1706 -> 0.1702 m), a little better on
    # acapulco, belgioioso, fhw, intel, worse on seattle, edmonton and infinite-corridor
    # (docs/journal/maps.md, session 21)
    lag_edges: bool = False
    # > 0: the odometry's forward motion as a second sequential edge between consecutive
    # keyframes (its scale taken out: the odometry's path length over the estimate's), this
    # spread (m, plus `odometry_per_metre` per metre of the edge) along the first keyframe's
    # heading, none across or in heading (`odometry_loose`); needs `close_loops(odometry=...)`
    # (`slam_trajectory` passes it; 0: off). `odometry_reach` > 0: only on edges farther than
    # this (m of path) from every accepted loop's end, added after the last round (the
    # stretches no loop reaches; 0: every edge, from the start). The default since session 24
    # (development seeds, paired, docs/journal/maps.md): freiburg-campus mean ATE 0.342 ->
    # 0.335 m, infinite-corridor 0.384 -> 0.377 (45 runs each, both beyond 2 SE), acapulco,
    # belgioioso and orebro a little better, no log worse; 0.04 m cost belgioioso and edmonton
    # 5 mm, and every edge (no reach) costs infinite-corridor 0.07-0.3 m
    odometry_along: float = 0.08
    odometry_per_metre: float = 0.0
    odometry_loose: tuple[float, float] = (1.0, 1.0)  # m across, rad: the edge's other spreads
    odometry_reach: float = 10.0
    # > 0: a sequential edge across a blind step (into a scan with too few returns to search,
    # `scanmap.SEARCH_MIN`, whose fit failed: the front end kept the odometry's step, slip
    # and all) that turns more than `blind_min_turn` (rad) gets this much heading spread
    # (rad) more, and its length times it across, so that the loops can take a slip out
    # there instead of spreading it over the stretch; needs `close_loops(step_fit=...)`
    # (`slam_trajectory` passes it; 0: off). The default since session 25 (development seeds,
    # docs/journal/maps.md): freiburg-campus drift seed 45 (a 40 degree slip at scan 925, 17
    # returns) 1.719 -> 0.338 m, mirrored drift 1.708 -> 0.288, seed 30 (13 degrees at 1337)
    # 0.442 -> 0.340; the other 45 seeds 8 changed, within noise (-0.0017 +- 0.0049 m over
    # 47 without seed 45); no other real log and no simulator log has a scan that sparse (the
    # same poses). Without the turn gate every freiburg-campus seed moves (+-0.09 m)
    blind_turn: float = 1.5
    blind_min_turn: float = 0.2
    # > 0 (rad): a sequential edge across a step whose poor fit (under `scan_map.lost`) a
    # search's unclear winner, fitting more of the returns, turns by more than this (the front
    # end's `doubt`: it kept the fit held, the rival may be right) is loosened as a blind
    # step's is (`blind_turn`), so that the loops choose between them (0: off). An expert
    # setting, off (session 37, the lead; docs/journal/maps.md): 0.05 mends freiburg-campus
    # drift seed 385 (a 0.107 rad slip under `turn_check`, the search's right winner refused)
    # 0.629 -> 0.302 m, but moves every campus run by up to +-0.1 m: development seeds 0-120
    # -0.0027 +- 0.0082 m, held out (471-480) +0.019 m; the nine other logs equal but 2 of 369
    doubted: float = 0.0
    # > 0 (rad): as `doubted`, on the steps whose logged odometry turns more than
    # `scan_map.turn_check` only (those the front end checks for a wheel slip): a slip it kept
    # there, on a poor fit with a rival that fits more and turns the step otherwise, is left
    # for the loops to take out; needs `close_loops(odometry=...)` (`slam_trajectory` passes
    # it; 0: off). The default since session 43 (docs/journal/maps.md): infinite-corridor
    # drift seed 724 (a 54 deg slip kept fitting 0.18 of the returns, the rival 60 deg away)
    # 3.30 -> 0.36 m. A sparse outdoor scan's doubts (freiburg-campus: rivals a reversed
    # corridor away, 1-3 rad, on nearly every seed) lie on steps the odometry turns a few
    # degrees, where `doubted` moved every campus run by up to 0.1 m either way; of 1,350
    # development runs this loosens a step on two (freiburg-campus 59, orebro 65: a slip
    # refused, the fit held right), and the loops keep it (-8 mm, +1 mm)
    doubted_slip: float = 0.5
    # > 0 (rad): a blind stretch (scans too sparse to search whose fit failed, between two
    # fitted scans) whose turn between its fitted ends differs from the odometry's by more
    # than this is re-derived from the two ends: the difference put on the one odometry step
    # it leaves turning least (a slip in one step), the odometry's steps composed from the
    # first end and the position left at the second spread along the stretch; needs
    # odometry (`slam_trajectory` passes it). An expert setting, off (session 27, blind27:
    # 0.25 on freiburg-campus drift seeds 0-50 mends 5 seeds' slips of 20-59 degrees, the
    # blind scans 18-58 -> 0.3-7.5 degrees off, the own per-metre heading error on seeds 0-5
    # 0.58 -> 0.25 degrees; ATE -0.0010 +- 0.0019 m, within noise; no other real log has one)
    blind_mend: float = 0.0
    # > 0 (rad): an excursion of the front end mended (`mend_excursions`): a step that turns
    # more than this against the odometry's (the return) after a stretch of at most
    # `excursion_span` scans entered by a weak fit (fewer than `min_inliers`) is a candidate;
    # the stretch is re-derived with the return's disagreement moved onto the entry step (the
    # return's step the odometry's), and kept if the returns of its scans within
    # `inlier_distance` of the `excursion_context` scans after the return rise by
    # `excursion_gain` of them. Needs odometry; 0 switches it off. The default since session
    # 29 (mend29: ten real logs x drift seeds 0-50 mend all 8 stretches > 0.2 rad off the
    # truth and nothing else, mirrored drift 7 of 8; intel seed 1 ATE 0.140 -> 0.068 m, its
    # 20 m error 0.81 -> 0.14 m; freiburg-campus 20 m error -0.025 +- 0.025 m, ATE within
    # noise on every log. Held out, seeds 51-80: 4 freiburg-campus runs mended, 20 m error
    # 0.41-0.49 -> 0.22-0.33 m on each, ATE -0.0024 +- 0.0041 m, no other run changed)
    excursion_mend: float = 0.2
    excursion_span: int = 40
    excursion_context: int = 10
    excursion_gain: float = 0.05
    loop: LoopConfig = field(default_factory=LoopConfig)
    front_end: str = "map"  # sequential matching: "map" (scan-to-map) or "keyframe" (the paper's)
    scan_map: MapConfig = field(default_factory=MapConfig)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def maps_scan_to_map(self, method: str, with_odometry: bool) -> bool:
        """Whether a log is matched by the scan-to-map front end (`scan_map`): the gaussian
        method, the "map" front end and odometry for its motion model; else the keyframe
        front end (the pair matcher, or ICP). The one place this is decided."""
        return method == "gaussian" and self.front_end == "map" and with_odometry


@dataclass
class SlamResult:
    """Poses per scan before and after loop closure, the graph and the loops."""

    poses: np.ndarray  # S x 3, after loops
    before: np.ndarray  # S x 3, sequential only
    keys: np.ndarray  # keyframe scan indices (the graph's nodes)
    edges: list[pg.Edge]
    loops: list[Loop]  # every verified candidate, accepted or not
    seconds: float  # matching + loops + optimisation
    timings: dict[str, float]
    config: dict[str, Any]

    def graph(self) -> tuple[Any, Any]:
        """GTSAM graph and optimised values (for `graph.g2o`)."""
        graph, values = pg.factor_graph(self.keys, self.poses[self.keys], self.edges)
        return graph, values

    def loop_table(self, truth: np.ndarray | None = None) -> list[dict[str, Any]]:
        """Every verified candidate with its fitness (and truth residual when known)."""
        rows = []
        for lp in self.loops:
            row: dict[str, Any] = {
                "a": lp.a,
                "b": lp.b,
                "x": float(lp.pose[0]),
                "y": float(lp.pose[1]),
                "theta": float(lp.pose[2]),
                "score": lp.score,
                "inliers": lp.inliers,
                "ambiguity": lp.ambiguity,
                "accepted": lp.accepted,
                "reason": lp.reason,
                # a corridor loop: the axis (a's frame) along which it claims nothing
                "corridor": lp.axis is not None,
                "axis_x": float(lp.axis[0]) if lp.axis is not None else 0.0,
                "axis_y": float(lp.axis[1]) if lp.axis is not None else 0.0,
            }
            if truth is not None:
                et, er = loop_truth_error(lp, truth)
                row |= {
                    "truth_error_m": et,
                    "truth_error_deg": er,
                    "false": is_false_loop(lp, truth),
                }
            rows.append(row)
        return rows

    def summary(self, truth: np.ndarray | None = None) -> dict[str, Any]:
        accepted = [lp for lp in self.loops if lp.accepted]
        out: dict[str, Any] = {"loops": len(accepted), "candidates": len(self.loops)}
        if truth is not None:
            table = self.loop_table(truth)
            out["false_loops"] = sum(1 for r in table if r["accepted"] and r["false"])
        return out


def keyframes_of(poses: np.ndarray, distance: float, angle: float) -> np.ndarray:
    """Keyframe scan indices along `poses`: scan 0 and each scan that moved `distance` or turned
    `angle` since the last keyframe."""
    ref = sc.keyframes(poses, distance, angle)
    keys = np.unique(np.concatenate([[0], ref[1:]]))
    return keys


def sequential_edges(
    keys: np.ndarray,
    poses: np.ndarray,
    config: SlamConfig,
    step_cov: np.ndarray | None = None,
) -> list[pg.Edge]:
    """Edges between consecutive keyframes: the sequential estimate, spread floored and grown
    with the edge's length; with `config.matcher_cov` and `step_cov` (S-1 x 3 x 3, world
    frame, pair k = scan k -> k+1), the front end's own covariances instead."""
    rel = se2.between(poses[keys[:-1]], poses[keys[1:]])
    if config.matcher_cov > 0 and step_cov is not None and len(keys) > 1:
        return [
            pg.Edge(int(a), int(b), r, c)
            for a, b, r, c in zip(
                keys[:-1], keys[1:], rel, _chain_cov(keys, poses, step_cov, config), strict=True
            )
        ]
    length = np.hypot(rel[:, 0], rel[:, 1]) + 0.3 * np.abs(rel[:, 2])
    st = config.sigma_floor[0] + config.sigma_per_metre[0] * length
    sr = config.sigma_floor[1] + config.sigma_per_metre[1] * length
    return [
        pg.Edge(int(a), int(b), r, np.diag([t * t, t * t, q * q]))
        for a, b, r, t, q in zip(keys[:-1], keys[1:], rel, st, sr, strict=True)
    ]


def _chain_cov(
    keys: np.ndarray, poses: np.ndarray, step_cov: np.ndarray, config: SlamConfig
) -> np.ndarray:
    """Per keyframe edge: the steps' covariances (world frame) turned into the frame of each
    step's first scan and summed over the edge (the lever arm of a multi-step edge left out:
    on these logs a keyframe is one or two scans), times `matcher_cov` squared, plus the floor."""
    turn = np.zeros((len(poses) - 1, 3))
    turn[:, 2] = -poses[:-1, 2]  # world axes to each step's first scan's: a rotation only
    rot = consistency.adjoint(turn)
    local = rot @ step_cov @ rot.transpose(0, 2, 1)
    summed = np.concatenate([np.zeros((1, 3, 3)), np.cumsum(local, axis=0)])
    per_edge = summed[keys[1:]] - summed[keys[:-1]]
    t, r = config.matcher_floor
    out: np.ndarray = per_edge * config.matcher_cov**2 + np.diag([t * t, t * t, r * r])
    return out


def unverified(ranges: np.ndarray, step_fit: np.ndarray, config: SlamConfig) -> np.ndarray:
    """(S - 1,) bool, pair k = scan k -> k+1: the steps into scans the scan-to-map front end
    could not verify (fewer returns than it searches, `SEARCH_MIN`, and a fit with fewer than
    `min_inliers` of them within reach of the map), whose heading is the odometry's."""
    cfg = config.scan_map
    out: np.ndarray = (returns(ranges[1:], cfg.max_range) < SEARCH_MIN) & (
        np.asarray(step_fit) < cfg.min_inliers
    )
    return out


def step_turns(poses: np.ndarray) -> np.ndarray:
    """Each step's turn (S - 1, rad, signed) along `poses` (S x 3)."""
    turns: np.ndarray = se2.between(poses[:-1], poses[1:])[:, 2]
    return turns


def blind_steps(
    ranges: np.ndarray, step_fit: np.ndarray, before: np.ndarray, config: SlamConfig
) -> np.ndarray:
    """The `unverified` steps that turn (in the estimate `before`) more than
    `blind_min_turn`: where a slip may hide."""
    turn = np.abs(step_turns(before))
    out: np.ndarray = unverified(ranges, step_fit, config) & (turn > config.blind_min_turn)
    return out


def doubted_steps(
    step_doubt: np.ndarray, odometry: np.ndarray | None, config: SlamConfig
) -> np.ndarray:
    """The steps whose edge the loops should choose across (`SlamConfig.doubted`, and
    `doubted_slip` where the logged odometry turns more than `scan_map.turn_check`)."""
    out = step_doubt > config.doubted if config.doubted > 0 else np.zeros(len(step_doubt), bool)
    if config.doubted_slip > 0 and odometry is not None:
        turn = np.abs(step_turns(odometry))
        out |= (step_doubt > config.doubted_slip) & (turn > config.scan_map.turn_check)
    return out


def mend_blind(
    ranges: np.ndarray,
    step_fit: np.ndarray,
    before: np.ndarray,
    odometry: np.ndarray,
    config: SlamConfig,
) -> np.ndarray:
    """`before` with each blind stretch's poses re-derived from its two fitted ends
    (`SlamConfig.blind_mend`): the front end kept the odometry's steps there, so a slip in
    one of them stays in the blind scans' poses even when the next fitted scan takes it out;
    the turn the ends disagree with the odometry by goes on the step it leaves turning least.
    Poses outside the stretches that need it are returned unchanged (the same array)."""
    if config.blind_mend <= 0:
        return before
    blind = np.r_[False, unverified(ranges, step_fit, config)]
    if not blind.any():
        return before
    edge = np.diff(np.concatenate([[0], blind.astype(np.int8), [0]]))
    out = before
    for s, e in zip(np.flatnonzero(edge == 1), np.flatnonzero(edge == -1), strict=True):
        if s < 1 or e >= len(before):
            continue  # no fitted scan on one side
        a, b = int(s) - 1, int(e)
        steps = se2.between(odometry[a:b], odometry[a + 1 : b + 1])
        turns = steps[:, 2]
        c = float(se2.wrap(se2.between(before[a], before[b])[2] - turns.sum()))
        if abs(c) <= config.blind_mend:
            continue
        worst = np.where(np.eye(len(turns), dtype=bool), np.abs(turns + c), np.abs(turns))
        steps[int(np.argmin(worst.max(axis=1))), 2] += c
        if out is before:
            out = before.copy()
        out[s:b] = _rederive(before, a, b, steps)[1:-1]
    return out


def _rederive(before: np.ndarray, a: int, b: int, steps: np.ndarray) -> np.ndarray:
    """Poses a..b (inclusive) composed from `before[a]` along `steps` (b - a, each in its first
    pose's frame), the position left at b spread along the stretch by path length (a and b
    keep theirs; the heading is the steps')."""
    head = before[a, 2] + np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    cos, sin = np.cos(head[:-1]), np.sin(head[:-1])
    moves = np.stack(
        [cos * steps[:, 0] - sin * steps[:, 1], sin * steps[:, 0] + cos * steps[:, 1]], 1
    )
    xy = before[a, :2] + np.concatenate([[[0.0, 0.0]], np.cumsum(moves, axis=0)])
    length = np.concatenate([[0.0], np.cumsum(np.hypot(moves[:, 0], moves[:, 1]))])
    share = length / length[-1] if length[-1] > 0 else np.linspace(0.0, 1.0, len(length))
    xy += share[:, None] * (before[b, :2] - xy[-1])
    out: np.ndarray = np.column_stack([xy, se2.wrap(head)])
    return out


def _returns_within(
    ranges: np.ndarray, laser: LaserGeometry, poses: np.ndarray, limit: float
) -> np.ndarray:
    """The returns (within `limit`) of scans `ranges` (N x B) at robot poses `poses` (N x 3),
    in the world frame, as one P x 2 array (`toolkit.raster.world_points`)."""
    r = np.asarray(ranges, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        r = np.where((r > 0) & (r <= limit), r, np.nan)
    return world_points(r, poses, laser)[0]


def mend_excursions(
    ranges: np.ndarray,
    laser: LaserGeometry,
    step_fit: np.ndarray,
    before: np.ndarray,
    odometry: np.ndarray,
    config: SlamConfig,
) -> np.ndarray:
    """`before` with the front end's excursions mended (`SlamConfig.excursion_mend`): the
    odometry slips at a step the front end cannot fit well (the entry), the front end follows
    it, matches the next scans against a map that now holds the misplaced ones, and a later
    step (the return) finds the older map again and turns the slip back, the odometry not
    turning there. The stretch between keeps the slip unless re-derived: the return's
    disagreement with the odometry moved onto the entry step, the positions re-composed
    (`_rederive`). Truth-free arbiter: the stretch's returns within `inlier_distance` of the
    returns of the `excursion_context` scans on each side, mended against as placed; a right
    front end and a slipped odometry at the return scores the other way. Poses outside the
    stretches mended are returned unchanged (the same array)."""
    if config.excursion_mend <= 0:
        return before
    cfg = config.scan_map
    d = se2.wrap(step_turns(before) - step_turns(odometry))
    if not np.any(np.abs(d) > config.excursion_mend):
        return before  # no return: scipy.spatial not loaded (0.3-0.5 s on a map's start)
    from scipy.spatial import cKDTree  # noqa: PLC0415

    weak = np.asarray(step_fit) < cfg.min_inliers
    out = before
    last = 0  # a stretch is mended once: the next return looks only after it
    for k in np.flatnonzero(np.abs(d) > config.excursion_mend):
        b = int(k) + 1  # the return: step k, scan k -> b
        lo = max(last, b - config.excursion_span, 1)
        # entries: weak steps e (scan e -> e + 1) with no other large disagreement up to k
        big = np.flatnonzero(np.abs(d[lo - 1 : k]) > config.excursion_mend)
        if len(big):
            lo = lo + int(big[-1])
        entries = np.flatnonzero(weak[lo - 1 : k]) + lo - 1
        if len(entries) == 0:
            continue
        ctx = np.arange(b, min(b + config.excursion_context + 1, len(out)))
        tree = cKDTree(_returns_within(ranges[ctx], laser, out[ctx], cfg.max_range))
        best, most = None, 0
        for e in entries:
            a = int(e)
            steps = se2.between(out[a:b], out[a + 1 : b + 1])
            steps[0, 2] += d[k]
            steps[-1] = se2.between(odometry[b - 1], odometry[b])  # the return: the odometry
            mended = _rederive(out, a, b, steps)[1:-1]
            fits = []
            for poses in (out[a + 1 : b], mended):
                pts = _returns_within(ranges[a + 1 : b], laser, poses, cfg.max_range)
                fits.append(
                    np.isfinite(tree.query(pts, distance_upper_bound=cfg.inlier_distance)[0])
                )
            # kept if the share rises by the gain; of those, the most returns gained wins (a
            # longer stretch whose added scans fit better too)
            gained = int(fits[1].sum()) - int(fits[0].sum())
            if len(fits[0]) and gained > config.excursion_gain * len(fits[0]) and gained > most:
                best, most = (a, mended), gained
        if best is not None:
            a, mended = best
            if out is before:
                out = before.copy()
            out[a + 1 : b] = mended
            last = b
    return out


def loosen_blind(
    edges: list[pg.Edge], keys: np.ndarray, blind: np.ndarray, config: SlamConfig
) -> list[pg.Edge]:
    """`edges` (one per consecutive keyframe pair) with those across a blind step given
    `blind_turn` more heading spread and the edge's length times it more across both axes:
    a slip of the odometry's that no fit saw may lie there."""
    if config.blind_turn <= 0 or not blind.any():
        return edges
    counts = np.concatenate([[0], np.cumsum(blind)])
    across = counts[keys[1:]] - counts[keys[:-1]] > 0
    out = list(edges)
    turn = config.blind_turn
    for m in np.flatnonzero(across):
        e = edges[m]
        t = float(np.hypot(e.pose[0], e.pose[1])) * turn
        cov = e.covariance + np.diag([t * t, t * t, turn * turn])
        out[m] = pg.Edge(e.a, e.b, e.pose, cov, e.loop)
    return out


def odometry_edges(
    keys: np.ndarray, before: np.ndarray, odometry: np.ndarray, config: SlamConfig
) -> list[pg.Edge]:
    """Per consecutive keyframe pair: the odometry's motion, its scale taken out (the
    odometry's keyframe path over `before`'s), tight only along the first keyframe's heading
    (`SlamConfig.odometry_along`): wheels measure the forward motion well over many steps once
    their scale is known, the heading poorly (a wheel-diameter drift, noise of ~1 deg a step)."""
    if config.odometry_along <= 0 or len(keys) < 2:
        return []
    rel = se2.between(odometry[keys[:-1]], odometry[keys[1:]])
    est = se2.between(before[keys[:-1]], before[keys[1:]])
    length = np.hypot(est[:, 0], est[:, 1])
    odo_length = np.hypot(rel[:, 0], rel[:, 1])
    scale = float(odo_length.sum() / length.sum()) if length.sum() > 0 else 1.0
    rel[:, :2] /= scale if scale > 0 else 1.0
    along = config.odometry_along + config.odometry_per_metre * length
    across, turn = config.odometry_loose
    return [
        pg.Edge(int(a), int(b), r, np.diag([t * t, across * across, turn * turn]))
        for a, b, r, t in zip(keys[:-1], keys[1:], rel, along, strict=True)
    ]


def local_map_edges(
    ds: Dataset,
    keys: np.ndarray,
    poses: np.ndarray,
    config: SlamConfig,
    match: sc.MatchConfig | None = None,
) -> list[pg.Edge]:
    """Each keyframe matched against the 2nd .. `local_map`-th keyframe before it (the local
    map: the recent keyframes' returns in beam order), by the Gaussian scan matcher seeded with
    the sequential estimate; all pairs of one lag at once. Matches that fell back on the seed
    or that few returns agree with are left out. The keyframe front end's; the scan-to-map
    front end's only with `lag_edges`."""
    if config.local_map < 2 or len(keys) < 3:
        return []
    if config.front_end != "keyframe" and not config.lag_edges:
        return []
    ranges = np.ascontiguousarray(ds.ranges[keys])
    kp = poses[keys]
    m = np.arange(len(keys))
    edges: list[pg.Edge] = []
    for lag in range(2, config.local_map + 1):
        ref = np.maximum(m - lag, 0)
        robot_seed = se2.between(kp[ref[1:]], kp[1:])
        seeds = se2.laser_motion(robot_seed, ds.laser)
        found = sc.match_pairs(ranges, seeds, ds.laser, match, ref)
        rel = se2.robot_motion(found.pose, ds.laser)
        good = (m[1:] >= lag) & (found.degenerate < 2) & (found.agreement >= config.min_agreement)
        length = np.hypot(rel[:, 0], rel[:, 1]) + 0.3 * np.abs(rel[:, 2])
        st = config.sigma_floor[0] + config.sigma_per_metre[0] * length
        sr = config.sigma_floor[1] + config.sigma_per_metre[1] * length
        if config.local_map_turn > 0:
            sr = np.full_like(sr, config.local_map_turn)
        for k in np.nonzero(good)[0]:
            a, b = int(keys[ref[k + 1]]), int(keys[k + 1])
            cov = np.diag([st[k] ** 2, st[k] ** 2, sr[k] ** 2])
            edges.append(pg.Edge(a, b, rel[k], cov, loop=True))  # robust, as loops
    return edges


def restarted(
    graph: gtsam.NonlinearFactorGraph,
    keys: np.ndarray,
    edges: list[pg.Edge],
    first: np.ndarray,
    current: np.ndarray,
    config: SlamConfig,
) -> np.ndarray:
    """`current` (an optimum of `graph` from the last one), or the optimum from LAGO's start
    (`SlamConfig.lago_restart`) when the graph's error there is under that share of its own:
    the warm start's may be a local minimum with a stretch turned far."""
    try:
        start = pg.lago_start(keys, edges, first)
    except (ValueError, IndexError, RuntimeError):  # GTSAM refuses the graph: keep the optimum
        return current
    other = pg.optimise(graph, pg.initial_values(keys, start), keys)
    if pg.error(graph, keys, other) < config.lago_restart * pg.error(graph, keys, current):
        return other
    return current


def hang(keys: np.ndarray, before: np.ndarray, optimised: np.ndarray) -> np.ndarray:
    """Every scan's pose: its last keyframe's optimised pose composed with the scan's offset
    from that keyframe in the sequential estimate."""
    owner = keys[np.searchsorted(keys, np.arange(len(before)), side="right") - 1]
    index = np.searchsorted(keys, owner)
    offset = se2.between(before[owner], before)
    return se2.compose(optimised[index], offset)


#: reasons of loops withdrawn after optimising, which no later round brings back
WITHDRAWN = ("residual", "slid")


def corridor_slides(loops: Sequence[Loop], keys: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """How far (m) the keyframe poses `poses` (of `keys`) put each loop's scan b from the
    loop's pose along its corridor axis (0 for a full loop): a corridor loop takes its along
    position from the trajectory it was matched on, and the optimum, pinned along by full
    loops, may move b metres further (`LoopConfig.corridor_slide`)."""
    out = np.zeros(len(loops))
    for m, lp in enumerate(loops):
        if lp.axis is not None:
            ia, ib = np.searchsorted(keys, [lp.a, lp.b])
            rel = se2.between(poses[ia], poses[ib])
            out[m] = abs(float((rel[:2] - lp.pose[:2]) @ lp.axis))
    return out


def close_loops(
    ds: Dataset,
    before: np.ndarray,
    config: SlamConfig | None = None,
    step_cov: np.ndarray | None = None,
    odometry: np.ndarray | None = None,
    step_fit: np.ndarray | None = None,
    step_doubt: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, list[pg.Edge], list[Loop], dict[str, float], np.ndarray]:
    """Local-map edges, loop closure and pose graph optimisation over a sequential estimate
    `before` (S x 3); returns the poses, keyframes, edges, loops, timings and the estimate
    before loops (with the local map). `odometry` (S x 3): for `SlamConfig.odometry_along`,
    `LoopConfig.query_odometry` and `doubted_slip`;
    `step_fit` (S - 1, the inlier share of each scan's fit): for `SlamConfig.blind_turn`;
    `step_doubt` (S - 1, the front end's `doubt` of each step): for `SlamConfig.doubted` and
    `doubted_slip` (which also needs `odometry`)."""
    config = config or SlamConfig()
    timings = {"loops": 0.0, "optimisation": 0.0}
    keys = keyframes_of(before, config.keyframe_distance, config.keyframe_angle)
    edges = sequential_edges(keys, before, config, step_cov)
    if config.blind_turn > 0 and step_fit is not None:
        loose = blind_steps(ds.ranges, step_fit, before, config)
        if step_doubt is not None:
            loose |= doubted_steps(np.asarray(step_doubt), odometry, config)
        edges = loosen_blind(edges, keys, loose, config)
    sequential_only = list(edges)
    odo_edges = odometry_edges(keys, before, odometry, config) if odometry is not None else []
    if odo_edges and config.odometry_reach <= 0:
        edges = edges + odo_edges  # everywhere, from the start
    if not config.loops or len(keys) < 3:
        return before.copy(), keys, edges, [], timings, before
    t0 = time.perf_counter()
    local = local_map_edges(ds, keys, before, config)
    timings["local_map"] = time.perf_counter() - t0
    if local:  # the sequential estimate, with the local map: before loops
        edges = edges + local
        t0 = time.perf_counter()
        graph, values = pg.factor_graph(keys, before[keys], edges, config.robust)
        before = hang(keys, before, pg.optimise(graph, values, keys))
        timings["optimisation"] += time.perf_counter() - t0
    closer = LoopCloser(ds.ranges, ds.laser, config.loop, odometry)  # `query_odometry`
    found: dict[tuple[int, int], Loop] = {}
    along = path_length(before)
    start = before[keys]  # where the next optimisation starts (`warm_start`: the last optimum)

    # the sequential (and local-map) edges' factors, built once for every optimisation
    t0 = time.perf_counter()
    fixed = pg.edge_factors(edges, config.robust)
    timings["optimisation"] += time.perf_counter() - t0
    rematch: list[Loop] = []  # corridor loops that slid, to match again (`corridor_rematch`)
    rematched: set[tuple[int, int]] = set()

    def solve() -> np.ndarray:
        """Optimise with the loops that passed the fitness test and agree with the loops
        nearby (`consistency.check`); drop those the optimum still contradicts."""
        nonlocal start
        t0 = time.perf_counter()
        fit = [lp for lp in found.values() if lp.fit and not lp.reason.startswith(WITHDRAWN)]
        for lp in fit:
            lp.accepted, lp.reason = True, ""
        drops = consistency.check(
            fit,
            keys,
            before,
            along,
            sequential_only,
            np.array(
                [lp.covariance(config.loop_sigma, config.loop.consistency_along) for lp in fit]
            ).reshape(-1, 3, 3),
            config.consistency_path,
            config.consistency_chi2,
            config.confirm,
        )
        for m, why in drops.items():
            fit[m].accepted, fit[m].reason = False, why
        accepted = [lp for lp in fit if lp.accepted]
        current = before[keys]
        for _ in range(3):
            loop_edges = [
                pg.Edge(lp.a, lp.b, lp.pose, lp.covariance(config.loop_sigma), loop=True)
                for lp in accepted
            ]
            graph, values = pg.factor_graph(keys, start, loop_edges, config.robust, fixed)
            current = pg.optimise(graph, values, keys)
            if not loop_edges:
                if config.warm_start:
                    start = current
                break
            chi2 = pg.residuals(current, keys, loop_edges)[:, 2]
            bad = chi2 > config.reject_chi2
            if bad.any() and config.lago_restart > 0:
                # `start` is still the graph's own (its prior holds start[0])
                current = restarted(graph, keys, edges + loop_edges, start[0], current, config)
                chi2 = pg.residuals(current, keys, loop_edges)[:, 2]
                bad = chi2 > config.reject_chi2
            if config.warm_start:
                start = current
            slid = corridor_slides(accepted, keys, current)
            gone = (slid > config.loop.corridor_slide) & (config.loop.corridor_slide > 0)
            if not (bad | gone).any():
                break
            for lp, drop, c, off, moved in zip(accepted, bad, chi2, gone, slid, strict=True):
                if drop:
                    lp.accepted = False
                    lp.reason = f"residual: chi2 {c:.1f} > {config.reject_chi2:g} after optimising"
                elif off:
                    lp.accepted = False
                    lp.reason = (
                        f"slid: the optimum puts scan {lp.b} {moved:.1f} m along the corridor"
                        f" from the match (> {config.loop.corridor_slide:g})"
                    )
                    if config.loop.corridor_rematch and lp.pair not in rematched:
                        rematch.append(lp)
            accepted = [lp for lp in accepted if lp.accepted]
        timings["optimisation"] += time.perf_counter() - t0
        if rematch:  # matched again where the optimum puts b: the stretch it really saw
            placed = hang(keys, before, current)
            for lp in rematch:
                rematched.add(lp.pair)
                # the earlier keyframe nearest b where the optimum puts it: the stretch b saw
                early = keys[along[lp.b] - along[keys] > config.loop.gap]
                if len(early) == 0:
                    continue
                a = int(early[np.argmin(np.hypot(*(placed[early, :2] - placed[lp.b, :2]).T))])
                if (a, lp.b) in found:
                    continue
                again = closer.verify(a, lp.b, config.loop.radius, placed, along, keys)
                if again is not None:
                    again.recognised = lp.recognised
                    found[(a, lp.b)] = again
                    rematched.add((a, lp.b))
            rematch.clear()
            return solve()
        return hang(keys, before, current)

    # round 1: queries in path order; `incremental`: a loop that moves its scan noticeably is
    # optimised at once, so that later candidates are predicted from the corrected trajectory
    # (measured: no better on fhw seeds 0-1, intel, seattle seed 0, and slower: off)
    poses = before
    loop_cfg = config.loop
    if config.incremental:
        index = KeyIndex(keys, poses, along, loop_cfg)
        next_at = 0.0
        for q in range(len(keys)):
            if along[keys[q]] < next_at:
                continue
            t0 = time.perf_counter()
            cand = index.candidate(q)
            lp = closer.verify(*cand, poses, along, keys) if cand is not None else None
            timings["loops"] += time.perf_counter() - t0
            if cand is None:
                continue
            next_at = along[keys[q]] + loop_cfg.every
            if lp is None:
                continue
            found[lp.pair] = lp
            if lp.accepted:
                moved = se2.between(se2.between(poses[lp.a], poses[lp.b]), lp.pose)
                if np.hypot(moved[0], moved[1]) > 0.3 or abs(moved[2]) > 0.05:
                    poses = solve()
                    index = KeyIndex(keys, poses, along, loop_cfg)
    else:  # the same candidates, verified side by side (`LoopCloser.workers`)
        t0 = time.perf_counter()
        found |= {lp.pair: lp for lp in closer.find(keys, poses, loop_cfg)}
        timings["loops"] += time.perf_counter() - t0
    poses = solve()
    if loop_cfg.recognition:
        # candidates by appearance, where no loop closed yet, whatever the drift (a revisit
        # 6-37 m off is beyond every window): before the later rounds, which then search from
        # a trajectory those loops corrected (after them instead, and leaving out corridor
        # loops' queries as the wide round does: the worst infinite-corridor draws less
        # improved, 0.45-0.78 m against 0.34-0.40; docs/journal/maps.md, session 19)
        t0 = time.perf_counter()
        closed = np.array([lp.b for lp in found.values() if lp.accepted], dtype=np.int64)
        for lp in recognition.find(closer, keys, poses, along, loop_cfg, skip=closed, known=found):
            found.setdefault(lp.pair, lp)
        timings["loops"] += time.perf_counter() - t0
        poses = solve()
    # further rounds from the optimised trajectory where no loop closed yet: smaller windows,
    # then a last one as wide as the drift along the path between
    # (each with whether it leaves out corridor loops' queries)
    later = [(replace(loop_cfg, radius=0.5, growth=0.01, window=1.5), False)] * (config.rounds - 1)
    if config.wide_window > 0:
        # no corridor loops there: a window that wide across a corridor holds the corridors
        # alongside it too, and the true one may lie beyond it; nor their queries: a wider
        # window only holds more of the same corridor (queries ambiguous otherwise are searched
        # wide again: infinite-corridor seed 0, draw 2, 1.36 m without them, 1.03 m with them)
        wide = replace(config.loop, growth=config.wide_growth, window=config.wide_window)
        later.append((replace(wide, corridor=False), config.wide_skip_corridors))
    for round_cfg, skip_corridors in later:
        t0 = time.perf_counter()
        skip = [lp.b for lp in found.values() if lp.accepted]
        if skip_corridors:
            skip += [lp.b for lp in found.values() if lp.axis is not None]
        closed = np.array(skip, dtype=np.int64)
        # a pair verified before keeps its first verdict: not verified again
        for lp in closer.find(keys, poses, round_cfg, closed, known=found.keys()):
            found.setdefault(lp.pair, lp)
        timings["loops"] += time.perf_counter() - t0
        poses = solve()
    if odo_edges and config.odometry_reach > 0:
        # the stretches no loop reaches: their keyframe edges get the odometry's, solved again
        ends = np.sort([along[e] for lp in found.values() if lp.accepted for e in (lp.a, lp.b)])
        if len(ends):  # each edge's middle against the nearest loop end (sorted: no K x L)
            mid = 0.5 * (along[keys[:-1]] + along[keys[1:]])
            i = np.searchsorted(ends, mid)
            lower, upper = (
                ends[np.clip(i - 1, 0, len(ends) - 1)],
                ends[np.clip(i, 0, len(ends) - 1)],
            )
            far = np.minimum(np.abs(mid - lower), np.abs(upper - mid)) > config.odometry_reach
        else:
            far = np.ones(len(odo_edges), dtype=bool)
        extra = [e for e, f in zip(odo_edges, far, strict=True) if f]
        if extra:
            t0 = time.perf_counter()
            fixed.push_back(pg.edge_factors(extra, config.robust))
            edges = edges + extra
            timings["optimisation"] += time.perf_counter() - t0
            poses = solve()
    accepted = [lp for lp in found.values() if lp.accepted]
    edges = edges + [
        pg.Edge(lp.a, lp.b, lp.pose, lp.covariance(config.loop_sigma), loop=True) for lp in accepted
    ]
    return poses, keys, edges, list(found.values()), timings, before
