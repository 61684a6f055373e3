"""Classification (paper Eq. 7, 9): a probability per place for every scan, smoothed along the
path by an HMM over places, and the class with the highest posterior.

The evidence per scan (`class_scores`) is the descriptor classifier's log-probabilities
(`toolkit.features.places`) plus the per-beam model's tempered log-posterior
(`toolkit.features.likelihood`), or the per-beam model alone. It is normalised into
posteriors (Eq. 9) and smoothed along the trajectory (Eq. 7's conditioning on the map: the
previous scans, and with forward-backward, the default for a whole log, the following ones
too). In the HMM each scan counts for the path travelled since the previous one over
`evidence_length` (scans a few centimetres apart are not independent views; see
`evidence_weights`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numba
import numpy as np
import pandas as pd
from scipy.special import log_softmax

from toolkit.dataset import LaserGeometry
from toolkit.features.augment import canonical
from toolkit.features.descriptors import features, path_length
from toolkit.features.likelihood import CHUNK, loglik, per_class, softmax
from toolkit.features.model import Config, FeatureModel
from toolkit.features.places import RESEMBLE_SKIP, resemblance


@dataclass
class Labels:
    """Posteriors per scan over the model's classes, and the winning class."""

    classes: list[str]
    prob: np.ndarray  # (S, K) rows sum to 1
    label: np.ndarray  # (S,) str

    @property
    def confidence(self) -> np.ndarray:
        return np.asarray(self.prob.max(axis=1))

    def frame(self, t: np.ndarray) -> pd.DataFrame:
        """labels.parquet: t, p_<class> per class, label."""
        cols: dict[str, Any] = {"t": np.asarray(t, dtype=np.float64)}
        for k, name in enumerate(self.classes):
            cols[f"p_{name}"] = self.prob[:, k]
        cols["label"] = self.label.astype(str)
        return pd.DataFrame(cols)


# ---------------------------------------------------------------- smoothing (Eq. 7)


@numba.njit(cache=True)
def _forward_backward(
    emit: np.ndarray, eps: np.ndarray, backward: bool
) -> np.ndarray:  # pragma: no cover - numba
    s, k = emit.shape
    alpha = np.empty((s, k))
    prev = np.full(k, 1.0 / k)
    for t in range(s):
        total = 0.0
        for j in range(k):
            a = emit[t, j] * ((1.0 - eps[t]) * prev[j] + eps[t] / k)
            alpha[t, j] = a
            total += a
        for j in range(k):
            alpha[t, j] /= total
            prev[j] = alpha[t, j]
    if not backward:
        return alpha
    beta = np.ones(k)
    nxt = np.empty(k)
    for t in range(s - 1, -1, -1):
        if t < s - 1:
            mix = 0.0
            for j in range(k):
                nxt[j] = emit[t + 1, j] * beta[j]
                mix += nxt[j]
            total = 0.0
            for j in range(k):
                beta[j] = (1.0 - eps[t + 1]) * nxt[j] + eps[t + 1] * mix / k
                total += beta[j]
            for j in range(k):
                beta[j] /= total
        total = 0.0
        for j in range(k):
            alpha[t, j] *= beta[j]
            total += alpha[t, j]
        for j in range(k):
            alpha[t, j] /= total
    return alpha


@numba.njit(cache=True)
def _forward_backward_stages(
    emit: np.ndarray, eps: np.ndarray, stages: int, backward: bool
) -> np.ndarray:  # pragma: no cover - numba
    """`_forward_backward` with each place a chain of `stages` states: a step moves on to
    the next state with probability eps, and on from the last one to the first state of any
    place alike (eps / K each, itself included), so a place lasts `stages` switching lengths
    on average and a stay much shorter than one is unlikely (an Erlang dwell, not a
    geometric one). The posterior of a place sums its states."""
    s, k = emit.shape
    n = stages
    m = k * n
    alpha = np.empty((s, m))
    prev = np.full(m, 1.0 / m)
    for t in range(s):
        e = eps[t]
        leave = 0.0
        for j in range(k):
            leave += prev[j * n + n - 1] * e
        total = 0.0
        for j in range(k):
            for q in range(n):
                i = j * n + q
                a = prev[i] * (1.0 - e) + (prev[i - 1] * e if q > 0 else leave / k)
                a *= emit[t, j]
                alpha[t, i] = a
                total += a
        for i in range(m):
            alpha[t, i] /= total
            prev[i] = alpha[t, i]
    out = np.empty((s, k))
    beta = np.ones(m)
    nxt = np.empty(m)
    for t in range(s - 1, -1, -1):
        if backward and t < s - 1:
            e = eps[t + 1]
            enter = 0.0
            for j in range(k):
                enter += emit[t + 1, j] * beta[j * n]
            total = 0.0
            for j in range(k):
                for q in range(n):
                    i = j * n + q
                    stay = (1.0 - e) * emit[t + 1, j] * beta[i]
                    on = emit[t + 1, j] * beta[i + 1] if q < n - 1 else enter / k
                    nxt[i] = stay + e * on
                    total += nxt[i]
            for i in range(m):
                beta[i] = nxt[i] / total
        total = 0.0
        for j in range(k):
            v = 0.0
            for q in range(n):
                v += alpha[t, j * n + q] * beta[j * n + q]
            out[t, j] = v
            total += v
        for j in range(k):
            out[t, j] /= total
    return out


def switch_probability(config: Config, n: int, poses: np.ndarray | None) -> np.ndarray:
    """Per scan, the probability that the place changed since the previous scan: grows with
    the distance travelled (and turned, 1 rad ~ `turn_length` m) along the trajectory."""
    step = path_steps(n, poses, config.turn_length)
    if step is None:
        return np.full(n, config.switch_per_scan)
    step[:1] = 0.0
    eps = -np.expm1(-step / config.place_length)
    return np.asarray(np.clip(np.nan_to_num(eps, nan=config.switch_per_scan), 1e-6, 1.0))


def path_steps(n: int, poses: np.ndarray | None, turn_length: float = 1.0) -> np.ndarray | None:
    """Per scan, the distance travelled since the previous scan (m; turning 1 rad ~
    `turn_length` m; the first scan: inf, all it sees is new)."""
    if poses is None or len(poses) != n:
        return None
    step = np.full(n, np.inf)
    if n > 1:
        d = np.diff(poses[:, :2], axis=0)
        turn = np.abs(np.remainder(np.diff(poses[:, 2]) + np.pi, 2 * np.pi) - np.pi)
        step[1:] = np.hypot(d[:, 0], d[:, 1]) + turn_length * turn
    return step


def evidence_weights(config: Config, n: int, poses: np.ndarray | None) -> np.ndarray:
    """Per scan, the share of a scan's evidence the HMM gets from it: the path travelled since
    the previous scan over `evidence_length` (at most 1; a robot standing still adds none);
    1 without poses (or where a pose is NaN)."""
    step = path_steps(n, poses, config.turn_length)
    if step is None or not config.evidence_length:
        return np.ones(n)
    return np.nan_to_num(np.clip(step / config.evidence_length, 0.0, 1.0), nan=1.0)


@numba.njit(cache=True)
def _turn_starts(xy: np.ndarray, radius: float) -> np.ndarray:  # pragma: no cover - numba
    """Per scan, whether it starts a turn: it lies `radius` or more from the current turn's
    first scan (or its position is NaN)."""
    start = np.zeros(len(xy), dtype=np.bool_)
    first = 0
    for i in range(len(xy)):
        d = np.hypot(xy[i, 0] - xy[first, 0], xy[i, 1] - xy[first, 1])
        if i == 0 or not d < radius:
            start[i] = True
            first = i
    return start


def turn_groups(poses: np.ndarray, radius: float) -> np.ndarray:
    """Per scan, the index of its turn: consecutive scans within `radius` (m) of the turn's
    first scan, taken while the robot turns on one spot (a scan driven past is a turn of
    one)."""
    xy = np.ascontiguousarray(poses[:, :2], dtype=np.float64)
    return np.cumsum(_turn_starts(xy, float(radius))) - 1


def turns(poses: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """`turn_groups` per scan, and each turn's first scan (for `np.*.reduceat` over turns)."""
    group = turn_groups(poses, radius)
    return group, np.flatnonzero(np.r_[True, group[1:] != group[:-1]])


#: quantile of a scan's ranges whose largest over a turn tells a turn that sees far (a tenth
#: of the beams: a few headings along a way out, not one beam through a gap)
REACH_QUANTILE = 0.9


def turn_reach(ranges: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Per turn (its scans from `first`), the largest over its scans of the range a tenth of
    the beams reach past (`REACH_QUANTILE`; no return: inf), in m."""
    r = np.asarray(ranges, dtype=np.float64)
    r = np.where(np.isfinite(r), r, np.inf)
    reach = np.quantile(r, REACH_QUANTILE, axis=1, method="lower")  # a beam's own range
    return np.asarray(np.maximum.reduceat(reach, first))


def doorway_free(far: np.ndarray, k: int) -> np.ndarray:
    """Per turn, whether it sees far (`far`) and none of the `k` turns before or after it is
    enclosed: a turn at a doorway, next to a room's first or last scans, is not."""
    if not k or not len(far):
        return np.asarray(far)
    enclosed = np.r_[np.zeros(k, dtype=bool), ~far, np.zeros(k, dtype=bool)]
    near = np.lib.stride_tricks.sliding_window_view(enclosed, 2 * k + 1).any(axis=1)
    return np.asarray(far & ~near)


#: headings (rad) two ways out of a turn must be apart, centre to centre (a junction's
#: corridors: 90 degrees, less the spread of a way out seen from off its axis)
JUNCTION_SPREAD = np.pi / 3
#: heading bins round the circle in which a turn's beams are pooled (10 degrees each)
JUNCTION_BINS = 36


def junction_turns(
    ranges: np.ndarray,
    poses: np.ndarray,
    angles: np.ndarray,
    first: np.ndarray,
    reach: float,
    n_scans: int,
) -> np.ndarray:
    """Per turn (its scans from `first`), whether it is a junction's long turn: `n_scans`
    scans or more with two or more ways out `JUNCTION_SPREAD` apart or more. A way out is a
    run of heading bins (world frame, `JUNCTION_BINS`) in which most of the turn's beams
    reach past `reach` m (no return: far), between bins where most do not (bins no beam saw
    are skipped): ways down two corridors; a room seen out of its door has one.
    `angles`: the beams' bearings on the robot."""
    size = np.diff(np.r_[first, len(ranges)])
    out = np.zeros(len(first), dtype=bool)
    width = 2 * np.pi / JUNCTION_BINS
    for t in np.flatnonzero(size >= n_scans):  # a loop over the few long turns
        part = slice(first[t], first[t] + size[t])
        far = ~(np.asarray(ranges[part], dtype=np.float64) <= reach)  # NaN / inf: far
        heading = np.mod(poses[part, 2, None] + angles[None, :], 2 * np.pi)
        b = np.minimum((heading / width).astype(np.int64), JUNCTION_BINS - 1).ravel()
        seen = np.bincount(b, minlength=JUNCTION_BINS)
        share = np.bincount(b, far.ravel(), minlength=JUNCTION_BINS)
        keep = np.flatnonzero(seen)
        wide = share[keep] * 2 > seen[keep]
        if wide.all() or not wide.any():
            continue
        k = int(np.flatnonzero(~wide)[0])  # start on a near bin: runs do not wrap
        wide, keep = np.roll(wide, -k), np.roll(keep, -k)
        edge = np.diff(np.r_[0, wide.astype(np.int64), 0])
        start, stop = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1) - 1
        if len(start) < 2:
            continue
        mid = np.angle(
            np.exp(1j * (keep[start] + 0.5) * width) + np.exp(1j * (keep[stop] + 0.5) * width)
        )
        apart = np.abs(np.angle(np.exp(1j * (mid[:, None] - mid[None, :]))))
        out[t] = bool((apart >= JUNCTION_SPREAD - 1e-9).any())
    return out


def pool_turns(
    config: Config,
    scores: np.ndarray,
    poses: np.ndarray | None,
    ranges: np.ndarray | None = None,
    angles: np.ndarray | None = None,
) -> np.ndarray:
    """The HMM's evidence (S x K log-probabilities) with each turn on the spot
    (`turn_groups` over `turn_pool` m) pooled: every scan of a turn gets the turn's mean (or,
    `turn_pool_rule` "max", per place the largest) log-probability, and the turn weighs
    together what its path without turning weighs (`evidence_weights` with no turn), spread
    evenly. A spot seen from several headings is one view of one place: a junction's four
    headings one vote, not four for the room they look like across; a room's turn still its
    room's. With `turn_pool_reach` (and `ranges`), a turn that does not see that far
    (`turn_reach`) is left as without pooling: an enclosed spot's few headings are all the
    evidence of a short stay; with `turn_pool_door` k, so is a far-seeing turn with an
    enclosed one among the k turns before or after it (the turn at a doorway: a room's first or
    last scans are next to it, and its headings that face the room are that short stay's
    evidence too). Without poses: `evidence_weights` alone."""
    n = len(scores)
    own = np.asarray(scores * evidence_weights(config, n, poses)[:, None])
    if poses is None or len(poses) != n or n == 0 or not config.turn_pool:
        return own
    group, first = turns(poses, config.turn_pool)
    size = np.diff(np.r_[first, n])
    if config.turn_pool_rule == "max":
        pooled = np.maximum.reduceat(scores, first, axis=0)
    else:
        pooled = np.add.reduceat(scores, first, axis=0) / size[:, None]
    weight = evidence_weights(replace(config, turn_length=0.0), n, poses)
    share = np.add.reduceat(weight, first) / size
    out = np.asarray(pooled[group] * share[group, None])
    if config.turn_pool_reach and ranges is not None and len(ranges) == n:
        far = turn_reach(ranges, first) > config.turn_pool_reach
        pooled_ok = doorway_free(far, config.turn_pool_door)
        if config.turn_pool_junction and angles is not None:
            pooled_ok |= far & junction_turns(
                ranges, poses, angles, first, config.turn_pool_reach, config.turn_pool_junction
            )
        out = np.where(pooled_ok[group, None], out, own)
    return out


@numba.njit(cache=True)
def _pass_starts(cell: np.ndarray, valid: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    """Per scan i, the first index of its pass: the run of consecutive scans before it whose
    cells (`cell`, S x 2 integer cell coordinates) lie within one cell of its own.
    Recomputed only where the cell changes (a scan in its predecessor's cell has its pass),
    so a robot standing in one cell costs one walk, not one per scan."""
    n = len(cell)
    first = np.empty(n, dtype=np.int64)
    for i in range(n):
        if not valid[i]:
            first[i] = i
            continue
        if i > 0 and valid[i - 1] and cell[i - 1, 0] == cell[i, 0] and cell[i - 1, 1] == cell[i, 1]:
            first[i] = first[i - 1]
            continue
        j = i
        while (
            j > 0
            and valid[j - 1]
            and abs(cell[j - 1, 0] - cell[i, 0]) <= 1
            and abs(cell[j - 1, 1] - cell[i, 1]) <= 1
        ):
            j -= 1
        first[i] = j
    return first


def _own_pass(cell: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per scan, the first and last index of its pass (`_pass_starts` forward, and on the
    log read backwards for the last)."""
    n = len(cell)
    back = _pass_starts(np.ascontiguousarray(cell[::-1]), np.ascontiguousarray(valid[::-1]))
    return _pass_starts(cell, valid), (n - 1 - back)[::-1]


#: the cells around a scan's own (and itself) whose scans are its neighbours in `pool_places`
BLOCK = [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)]


def pool_places(
    config: Config,
    scores: np.ndarray,
    poses: np.ndarray | None,
    ranges: np.ndarray | None = None,
) -> np.ndarray:
    """The evidence (S x K log-probabilities) of a scan mixed with that of the scans taken at
    the same spot on other passes: a place is where the robot is, so a junction driven
    through on one lap and turned in on another is one place. The plane is cut into square
    cells of `place_pool` m; a scan's neighbours are the scans in its cell and the eight
    around it (between `place_pool` and twice that from it) that are not on its own pass (the
    run of consecutive scans around it inside those cells: its own turn and its own drive
    past are its own evidence, counted once). Each neighbour weighs the path it drove to get
    there (`evidence_weights` with turning free) and brings its turn's mean (`turn_groups`
    over `TURN_SPOT`: a turn on the spot is one view, weighing its arrival's step); the
    scan's evidence becomes (own + share x the neighbours' weighted sum) / (1 + share x
    their weight), `place_pool_share` the share. Which scans take it: `place_pool_into`
    (`pool_receivers`). One pass of cell sums and a compiled walk for the passes: linear in
    the scans. Unchanged without poses or with `place_pool` 0. The poses must be consistent
    over the log (ground truth, a SLAM trajectory): with drifting odometry a lap's revisit
    lands elsewhere."""
    n = len(scores)
    if not config.place_pool or poses is None or len(poses) != n or n == 0:
        return scores
    xy = np.asarray(poses[:, :2], dtype=np.float64)
    valid = np.asarray(np.isfinite(xy).all(axis=1))
    if not valid.any():
        return scores
    cell = np.floor(xy / config.place_pool)  # cells on the frame's origin
    cell -= (cell.min(axis=0) if valid.all() else cell[valid].min(axis=0)) - 1
    cell[~valid] = 0.0
    cell = cell.astype(np.int64)  # from 1: the cells around stay >= 0
    width, height = (int(v) + 2 for v in cell.max(axis=0))
    key = cell[:, 0] * height + cell[:, 1]
    # each scan brings its turn's mean log-probability, weighted by the path it drove
    group, first = turns(poses, TURN_SPOT)  # a NaN pose starts a turn of its own
    size = np.diff(np.r_[first, n])
    weight = evidence_weights(replace(config, turn_length=0.0), n, poses) * valid
    brought = np.empty((n, scores.shape[1] + 1))  # per scan: evidence x weight, weight
    brought[:, :-1] = (np.add.reduceat(scores, first, axis=0) / size[:, None])[group]
    brought[:, :-1] *= weight[:, None]
    brought[:, -1] = weight
    block = _block_sums(key, brought, width, height, n)
    start, end = _own_pass(cell, valid)
    along = np.zeros((n + 1, brought.shape[1]))
    np.cumsum(brought, axis=0, out=along[1:])
    own = along[end + 1] - along[start]  # the scan's pass, in the block too
    other = block - own
    out = (scores + config.place_pool_share * other[:, :-1]) / (
        1.0 + config.place_pool_share * other[:, -1:]
    )
    revisit = valid & (other[:, -1] > REVISIT_WEIGHT)  # else its own, to the bit
    revisit &= pool_receivers(config, poses, ranges, group, first)
    return np.asarray(np.where(revisit[:, None], out, scores))


def _block_sums(
    key: np.ndarray, brought: np.ndarray, width: int, height: int, n: int
) -> np.ndarray:
    """Per scan, the sum of `brought` (S x C) over the scans in its cell (`key`, column-major
    over `width` x `height` cells with an empty border) and the eight around it: a dense grid
    of bincounts shifted nine times where the cells are few (4 per scan or fewer), else the
    occupied cells alone (np.unique) looked up nine times."""
    columns = brought.shape[1]
    if width * height <= max(4 * n, 1 << 16):
        grid = np.stack(
            [np.bincount(key, brought[:, c], width * height) for c in range(columns)], axis=1
        ).reshape(width, height, columns)
        block = sum(np.roll(grid, (dx, dy), axis=(0, 1)) for dx, dy in BLOCK)
        return np.asarray(np.reshape(block, (width * height, columns))[key])
    cells, at = np.unique(key, return_inverse=True)
    per_cell = np.stack([np.bincount(at, brought[:, c], len(cells)) for c in range(columns)], 1)
    around = np.zeros_like(per_cell)
    for dx, dy in BLOCK:  # nine shifted look-ups of the occupied cells, not per scan
        want = cells - (dx * height + dy)
        near = np.minimum(np.searchsorted(cells, want), len(cells) - 1)
        hit = cells[near] == want
        around[hit] += per_cell[near[hit]]
    return np.asarray(around[at])


def pool_receivers(
    config: Config,
    poses: np.ndarray,
    ranges: np.ndarray | None,
    group: np.ndarray,
    first: np.ndarray,
) -> np.ndarray:
    """Per scan, whether `pool_places` gives it the other passes' evidence
    (`place_pool_into`): "all"; "far", a scan of a turn (`group`, from `first`; a scan
    driven past is a turn of one) that sees past `turn_pool_reach` with no enclosed turn
    among the `turn_pool_door` before or after it (`pool_turns`' junction rule: not a
    doorway's nor a room's scans, whose place changes within a cell); "junctions", those
    of such turns on the spot (two scans or more): the corridor seen across, which looks
    like a room. Without `ranges` only "all" pools."""
    n = len(group)
    if config.place_pool_into == "all":
        return np.ones(n, dtype=bool)
    if ranges is None or len(ranges) != n:
        return np.zeros(n, dtype=bool)
    far = turn_reach(ranges, first) > config.turn_pool_reach
    take = doorway_free(far, config.turn_pool_door)
    if config.place_pool_into == "junctions":
        take &= np.diff(np.r_[first, n]) >= 2
    return np.asarray(take[group])


#: m: the scans within this of a turn's first are that turn (`pool_places`' view of a spot)
TURN_SPOT = 0.3
#: the other passes' weight (steps of `evidence_length`) under which a scan keeps its own
#: evidence in `pool_places`: the sums' rounding where no other pass is near
REVISIT_WEIGHT = 1e-9


def smooth(emit: np.ndarray, eps: np.ndarray, how: str, stages: int = 1) -> np.ndarray:
    """HMM over places: forward filter (the map so far) or forward-backward; with `stages`
    > 1, each place a chain of that many states (`_forward_backward_stages`)."""
    if how == "none":
        return emit
    emit, eps = np.ascontiguousarray(emit), np.ascontiguousarray(eps)
    if stages > 1:
        return _forward_backward_stages(emit, eps, stages, how != "forward")
    return _forward_backward(emit, eps, how != "forward")


# ---------------------------------------------------------------- the whole classification


def near_enclosed(
    model: FeatureModel, ranges: np.ndarray, poses: np.ndarray, scores: np.ndarray, chunk: int
) -> np.ndarray:
    """`scores` (S x K) with those of the scans of far-seeing turns (`turn_groups` over
    `turn_pool` m, `turn_reach` past `turn_pool_reach`) taken from `places_far`, the
    classifier without the view ahead's near bins (`Config.view_ahead_near_enclosed`). Why:
    in a small room seen turning in it, enclosed, the near bins tell it from the corridor; in
    a junction's turn they are the walls beside it, and the corridor looks like a room. With
    `view_ahead_near_door_free`, only the turns not at a doorway (`doorway_free`)."""
    cfg = model.config
    group, first = turns(poses, cfg.turn_pool)
    far_turn = turn_reach(ranges, first) > cfg.turn_pool_reach
    if cfg.view_ahead_near_door_free:  # not at a doorway (`view_ahead_near_door_free`)
        far_turn = doorway_free(far_turn, cfg.turn_pool_door)
    far = far_turn[group]
    if not far.any():
        return scores
    other = replace(model, places=model.places_far, config=replace(cfg, view_ahead_near_bins=False))
    alt = class_scores(other, ranges, chunk, None, poses)
    if cfg.view_ahead_near_average:  # log of the two posteriors' mean (`view_ahead_near_average`)
        alt = np.logaddexp(log_softmax(alt, axis=1), log_softmax(scores, axis=1)) - np.log(2.0)
    return np.where(far[:, None], alt, scores)


def classify(
    model: FeatureModel,
    ranges: np.ndarray,
    poses: np.ndarray | None = None,
    chunk: int = CHUNK,
    progress: Callable[[int], object] | None = None,
) -> Labels:
    """Posterior per class for every scan (Eq. 9), smoothed along the trajectory (Eq. 7).

    `poses` (S x 3: x, y, theta at the scan times) sets how fast places may change; without
    it a fixed switching probability per scan is used. `progress(m)`: m more scans scored.
    """
    model.check_laser(_laser_like(model, ranges))
    cfg = model.config
    scores = class_scores(model, ranges, chunk, progress, poses)
    if model.places_far is not None and poses is not None and len(poses) == len(ranges):
        scores = near_enclosed(model, ranges, poses, scores, chunk)
    if cfg.smoothing != "forward":  # the other passes: later ones too, not streaming
        scores = pool_places(cfg, scores, poses, ranges)
    if cfg.turn_pool and cfg.smoothing == "forward-backward":  # a turn's later scans too
        scores = pool_turns(cfg, scores, poses, ranges, model.laser.angles + model.laser.yaw)
    elif cfg.smoothing != "none" and cfg.evidence_length:
        scores *= evidence_weights(cfg, len(scores), poses)[:, None]
    prob = softmax(scores)
    if cfg.smoothing != "none":
        eps = switch_probability(cfg, len(prob), poses)
        prob = smooth(prob, eps, cfg.smoothing, cfg.dwell_stages)
    # the rules beside the laser look ahead and at the whole log's usual wall: not streaming
    opening_rules = cfg.beside_reach > 0 or cfg.narrow_opening > 0
    glass = cfg.glass_to is None or len(cfg.glass_to) == 2
    if (opening_rules or glass or cfg.room_margin > 0) and cfg.smoothing != "forward":
        view = side_view(ranges, model.laser)
        found = _dense_openings(ranges, model.laser, poses, view)
        if opening_rules:
            prob = _beside_only(prob, model, found)
        if glass:
            prob = glass_room(prob, model, ranges, view)
        if cfg.room_margin > 0:
            prob = room_margin(prob, model, found, view)
    classes = np.array(model.classes)
    return Labels(model.classes, prob, classes[prob.argmax(axis=1)])


# ---------------------------------------------------------------- an opening beside the laser

#: beams within this of square to the path (rad) see what is beside the laser
SQUARE = np.radians(3.0)
#: m past a side's usual wall that its square beams reach through an opening beside the
#: laser (a random world's rooms are 3-4 m deep behind their doors; a closed door's niche or
#: a box along the wall do not reach so far)
OPENING_DEPTH = 1.0


#: Per scan and side (S x 2: left, right), the median distance across the path the beams
#: square to it see (inf: no return), and per side the usual wall (`side_view`)
SideView = tuple[np.ndarray, np.ndarray]


def square_beams(laser: LaserGeometry) -> np.ndarray:
    """Per beam, whether it lies within `SQUARE` of square to the path: what it sees is
    beside the laser."""
    out: np.ndarray = np.abs(np.sin(laser.angles + laser.yaw)) >= np.cos(SQUARE) - 1e-9
    return out


def side_view(ranges: np.ndarray, laser: LaserGeometry) -> SideView | None:
    """Per scan and side (S x 2: left, right), the median distance across the path the beams
    square to it see (inf: no return), and per side the usual wall (the log's median; inf
    if no scan returns there); None without such beams on each side. Computed once per
    log and shared by the rules beside the laser (`openings`, `glass_room`)."""
    across = np.abs(np.sin(laser.angles + laser.yaw))
    side = np.sign(np.sin(laser.angles + laser.yaw))
    square = square_beams(laser)
    seen, wall = np.empty((len(ranges), 2)), np.full(2, np.inf)
    for k, sign in enumerate((1.0, -1.0)):
        beams = square & (side == sign)
        if not beams.any():
            return None
        r = np.asarray(ranges[:, beams], dtype=np.float64)
        seen[:, k] = np.median(np.where(np.isfinite(r), r, np.inf) * across[beams], axis=1)
        usual = seen[np.isfinite(seen[:, k]), k]
        if len(usual):
            wall[k] = float(np.median(usual))
    return seen, wall


def openings(
    ranges: np.ndarray,
    laser: LaserGeometry,
    poses: np.ndarray | None,
    view: SideView | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Per scan, the path (m) to the nearest scan with an opening beside it (its square
    beams, the median of their distances across the path, reach `OPENING_DEPTH` m past that
    side's usual wall; no return: open), the length along the path of that scan's run of
    consecutive such scans (the opening's length: a door's about 0.8 m), both inf where the
    log has none; and the laser's path from the first scan. None without poses or square
    beams. `view`: `side_view(ranges, laser)` when the caller has it."""
    view = side_view(ranges, laser) if view is None else view
    if view is None or poses is None or len(poses) != len(ranges):
        return None
    seen, wall = view
    beside = np.any(seen > wall + OPENING_DEPTH, axis=1)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    xy = poses[:, :2] + np.c_[laser.x * c - laser.y * s, laser.x * s + laser.y * c]
    along = np.r_[0.0, np.cumsum(np.nan_to_num(np.hypot(*np.diff(xy, axis=0).T)))]
    if not beside.any():
        return np.full(len(ranges), np.inf), np.full(len(ranges), np.inf), along
    idx = np.flatnonzero(beside)
    new = np.r_[True, np.diff(idx) > 1]  # the first scan of each run
    run = np.cumsum(new) - 1
    length = along[idx[np.r_[new[1:], True]]] - along[idx[new]]
    nearest, distance = _nearest(along[idx], along)
    return distance, length[run[nearest]], along


def _nearest(at: np.ndarray, along: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per position of `along`, the index of the nearest position of `at` (sorted, not
    empty) and the distance to it."""
    i = np.searchsorted(at, along)
    before, after = np.clip(i - 1, 0, len(at) - 1), np.clip(i, 0, len(at) - 1)
    to_before, to_after = np.abs(along - at[before]), np.abs(at[after] - along)
    return np.where(to_after < to_before, after, before), np.minimum(to_before, to_after)


#: the median path step (m) over which the openings are too coarse to place a door's edge
DENSE_STEP = 0.25
#: a taught place gets the reach rule if at least this share of its taught scans lie within
#: `beside_reach` of an opening beside the laser (doors, halls and corners all; a corridor's
#: none; docs/journal/places.md, session 24, taught24)
TAUGHT_NEAR = 0.9
#: m past the usual wall: a taught place's opening seen deeper (the median of its taught
#: scans that see an opening with returns) is a crossing corridor seen down (a corner's:
#: 2.8-24 m, median 18), not a door's room (2.6-4.0 m in the random worlds): no length rule
#: then (10 m let 7 corners of 290 worlds have it: the hall's precision (c) -0.0005)
ROOM_DEPTH = 5.0
#: m of path: the reach the places are learnt with when `beside_reach` is 0
LEARN_REACH = 0.5
#: m along the path: the room places of `glass_room` have all their taught openings this
#: short (`narrow_opening`'s default; a door's 0.9 m, a hall's 8-14 m)
LEARN_NARROW = 2.0
#: a taught place none of whose scans sees a room is glass if at least this share of its
#: taught scans has a square beam without return (random worlds' windows 0.4-1.0, every
#: other place 0 where it sees no room; docs/journal/places.md, session 25, door25)
GLASS_SHARE = 0.25


def _dense_openings(
    ranges: np.ndarray, laser: LaserGeometry, poses: np.ndarray | None, view: SideView | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """`openings`, or None where the rules do not apply: no poses, no square beams, fewer
    than two scans, or the median scan more than `DENSE_STEP` m from the last."""
    return _dense(openings(ranges, laser, poses, view) if len(ranges) >= 2 else None)


def _dense(
    found: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """`found` (`openings`), or None where the median scan lies more than `DENSE_STEP` m of
    path from the last (the path is too coarse to place an opening's edge)."""
    if found is None or not np.median(np.diff(found[2])) <= DENSE_STEP:
        return None
    return found


def learn_opening_places(
    ranges: np.ndarray,
    laser: LaserGeometry,
    poses: np.ndarray | None,
    training: dict[str, np.ndarray],
    reach: float,
    narrow: float,
) -> dict[str, tuple[str, ...]]:
    """Which taught places the rules beside the laser apply to, from the taught scans' own
    geometry, not their names: "beside" (the reach rule), the places whose taught scans
    (at least `TAUGHT_NEAR` of them) lie within `reach` m of path of an opening beside the
    laser and at least one of which sees through it to a wall (returns: not glass, not a
    window); "narrow" (the length rule), those of them whose taught scans' nearest openings
    are all at most `narrow` m long and not seen down deeper than `ROOM_DEPTH` (a door's
    room, not a crossing corridor). Both empty where `beside_only` would not apply (no poses,
    no square beams, a sparse log). For `glass_room`: "glass", the places none of whose
    taught scans sees a room beside the laser and at least `GLASS_SHARE` of which have a
    square beam without return (a window's pane returns only near normal, and not always);
    "room", of the "narrow" places learnt with `LEARN_REACH` and `LEARN_NARROW` on any path
    (a sparse log's too; empty without poses) the one whose room is seen deepest."""
    view = side_view(ranges, laser)
    if view is None:
        return {"beside": (), "narrow": (), "glass": (), "room": ()}
    seen, wall = view
    with np.errstate(invalid="ignore"):
        past = np.max(seen - wall, axis=1)  # the deeper side's reach past its wall
    room = np.isfinite(past) & (past > OPENING_DEPTH)
    pane = (~np.isfinite(np.asarray(ranges)[:, square_beams(laser)])).any(axis=1)
    taught = {
        name: np.asarray(idx, dtype=np.intp)
        for name, idx in training.items()
        if len(idx) and name != "none"
    }
    glass = tuple(
        k for k, i in taught.items() if not room[i].any() and pane[i].mean() >= GLASS_SHARE
    )

    def picks(
        found: tuple[np.ndarray, ...] | None, reach: float, narrow: float
    ) -> tuple[list[str], list[str]]:
        beside: list[str] = []
        short: list[str] = []
        if found is None:
            return beside, short
        distance, length = found[0], found[1]
        for name, idx in taught.items():
            near = np.mean(distance[idx] <= reach) >= TAUGHT_NEAR
            rooms = idx[room[idx]]
            if near and len(rooms):
                beside.append(name)
                if np.all(length[idx] <= narrow) and np.median(past[rooms]) <= ROOM_DEPTH:
                    short.append(name)
        return beside, short

    anywhere = openings(ranges, laser, poses, view) if len(ranges) >= 2 else None
    beside, short = picks(_dense(anywhere), reach or LEARN_REACH, narrow)
    rooms = picks(anywhere, LEARN_REACH, LEARN_NARROW)[1]
    if len(rooms) > 1:  # one: the deepest room seen (a corner of 290 worlds, its crossing
        # seen 2.8 m deep, had the length rule beside the door's room, 3.7 m; a tie-break
        # chosen on that world: the corner took the window's calls there)
        rooms = [max(rooms, key=lambda k: float(np.median(past[taught[k]][room[taught[k]]])))]
    return {"beside": tuple(beside), "narrow": tuple(short), "glass": glass, "room": tuple(rooms)}


def beside_only(
    prob: np.ndarray,
    model: FeatureModel,
    ranges: np.ndarray,
    poses: np.ndarray | None,
    view: SideView | None = None,
) -> np.ndarray:
    """The posteriors with places ruled out (their share given to the others) where the
    opening beside the laser says they are not: the places of `beside_places` at the scans
    more than `beside_reach` m of path from a scan with an opening beside the laser (a
    door's call runs a scan or two past its zone), those of `narrow_places` where that
    nearest opening is longer than `narrow_opening` m along the path (a hall's or a
    crossing corridor's, not a door's; `openings`; docs/journal/places.md, session 24);
    either None (the default): the places learnt when fitting (`model.opening_places`,
    `learn_opening_places`).
    Unchanged without poses, without beams square to the path, or where the median scan
    lies more than `DENSE_STEP` m from the last (the path is then too coarse); `classify`
    leaves it out when streaming (`smoothing` "forward": it looks at the scans ahead).
    `view`: `side_view(ranges, model.laser)` when the caller has it."""
    return _beside_only(prob, model, _dense_openings(ranges, model.laser, poses, view))


def _beside_only(
    prob: np.ndarray, model: FeatureModel, found: tuple[np.ndarray, ...] | None
) -> np.ndarray:
    """`beside_only` with the log's openings found (`_dense_openings`; None: unchanged)."""
    if found is None:
        return prob
    cfg = model.config
    names = list(model.classes)
    distance, length, _ = found
    out = prob.copy()
    learnt = model.opening_places
    rules = (
        (cfg.beside_reach, cfg.beside_places, learnt.get("beside", ()), distance),
        (cfg.narrow_opening, cfg.narrow_places, learnt.get("narrow", ()), length),
    )
    for limit, named, learnt_places, measure in rules:
        places = learnt_places if named is None else named
        columns = np.array([names.index(k) for k in places if k in names], int)
        if limit > 0 and len(columns):
            out[np.ix_(measure > limit, columns)] = 0.0
    total = out.sum(axis=1, keepdims=True)
    return np.where(total > 0, out / np.where(total > 0, total, 1.0), prob)


def room_beside(view: SideView) -> np.ndarray:
    """(S,) bool: the scans whose beams square to the path see, on either side, returns from
    `OPENING_DEPTH` to `ROOM_DEPTH` m past that side's usual wall (a room behind an opening)."""
    seen, wall = view
    with np.errstate(invalid="ignore"):
        past = seen - wall
    out: np.ndarray = np.any(
        np.isfinite(past) & (past > OPENING_DEPTH) & (past <= ROOM_DEPTH), axis=1
    )
    return out


def glass_room(
    prob: np.ndarray, model: FeatureModel, ranges: np.ndarray, view: SideView | None = None
) -> np.ndarray:
    """The posteriors with a call of a glass place given to a room place (the glass places'
    shares added to the room place's likeliest there) at the scans whose beams square to the
    path see, on either side, returns from `OPENING_DEPTH` to `ROOM_DEPTH` m past that
    side's usual wall (`side_view`; `view` when the caller has it): a room behind an opening,
    which a window's glass (no return, or the pane at the wall) never shows; a door across
    the path from a window was called window (docs/journal/places.md, session 24, glass24).
    The places: `glass_to`'s pair, or where it is None those learnt when fitting
    (`model.opening_places` "glass" and "room", `learn_opening_places`). Unchanged without
    beams square to the path or without places of both kinds."""
    names = list(model.classes)
    glass_places, room_places, _ = _places_of(model)
    g = np.array([names.index(k) for k in glass_places if k in names], int)
    r = np.array([names.index(k) for k in room_places if k in names and k not in glass_places], int)
    view = side_view(ranges, model.laser) if view is None else view
    if view is None or not len(g) or not len(r):
        return prob
    room = room_beside(view)
    hit = np.flatnonzero(room & np.isin(prob.argmax(axis=1), g))
    out = prob.copy()
    to = r[out[np.ix_(hit, r)].argmax(axis=1)] if len(r) > 1 else np.full(len(hit), r[0])
    share = out[hit, g[0]] if len(g) == 1 else out[np.ix_(hit, g)].sum(axis=1)
    out[hit, to] += share
    out[np.ix_(hit, g)] = 0.0
    return out


def _places_of(model: FeatureModel) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
    """The glass, room and reach ("beside") places of `model`: its config's names where
    given, else those learnt when fitting (`learn_opening_places`)."""
    cfg, learnt = model.config, model.opening_places
    glass, room = (
        (learnt.get("glass", ()), learnt.get("room", ()))
        if cfg.glass_to is None
        else (cfg.glass_to[:1], cfg.glass_to[1:])
    )
    beside = learnt.get("beside", ()) if cfg.beside_places is None else cfg.beside_places
    return glass, room, beside


def room_margin(
    prob: np.ndarray,
    model: FeatureModel,
    found: tuple[np.ndarray, ...] | None,
    view: SideView | None,
) -> np.ndarray:
    """The posteriors with a call of a place that has no opening of its own (not a reach
    place of `beside_only`, not the room place: the corridor, the window) given to the room
    place (its share added) where the room place is the runner-up and a scan called the room
    place whose square beams see a room beside the laser (`glass_room`'s 1-5 m) lies within
    `room_margin` m of path: a found door's zone runs on past its opening, where the scans
    see no room and were called corridor (docs/journal/places.md, session 25, door25).
    Unchanged where `beside_only` does not apply (`found`, the log's `_dense_openings`, is
    None: no poses, a sparse log) or without a room place; `view`: the log's `side_view`."""
    names = list(model.classes)
    _, rooms, beside = _places_of(model)
    if found is None or view is None or not rooms or rooms[0] not in names:
        return prob
    r = names.index(rooms[0])
    room = room_beside(view)
    order = np.argsort(-prob, axis=1, kind="stable")
    call, second = order[:, 0], order[:, 1]
    anchor = np.flatnonzero(room & (call == r))
    if not len(anchor):
        return prob
    distance = _nearest(found[2][anchor], found[2])[1]
    sources = [k for k, name in enumerate(names) if name not in (*beside, rooms[0], "none")]
    hit = np.flatnonzero(
        np.isin(call, sources) & (second == r) & (distance <= model.config.room_margin)
    )
    out = prob.copy()
    out[hit, r] += out[hit, call[hit]]
    out[hit, call[hit]] = 0.0
    return out


#: Scans scored at once between two progress steps (every scan is scored on its own: the
#: blocks do not change the result). Smaller blocks cost: each starts the parallel kernels
#: anew (4096 scored 35,000 scans/s, 16,384 and 65,536 about 70,000, on 2 loaded cores).
SCANS_PER_STEP = 16_384


def class_scores(
    model: FeatureModel,
    ranges: np.ndarray,
    chunk: int = CHUNK,
    progress: Callable[[int], object] | None = None,
    poses: np.ndarray | None = None,
) -> np.ndarray:
    """Per scan and class, the log-score the HMM takes as evidence (S, K): the descriptor
    classifier's log-probabilities (on the descriptors and their context along `poses`'
    path), plus `beam_term` times the per-beam model's tempered
    log-posterior; without descriptors, the per-beam model's tempered log-likelihood. Scored
    in blocks of `SCANS_PER_STEP` scans, `progress(m)` after each."""
    cfg = model.config
    out = np.empty((len(ranges), len(model.classes)))
    columns = cfg.columns()
    along = path_length(len(ranges), poses)
    factor = 1.0  # the log's widths rescaled to the canonical one, or the log stretched
    if cfg.descriptors and model.places is not None:
        ranges, factor = canonical(ranges, model.laser, cfg.canonical_width, cfg.canonical_how)
    check = None  # the places whose calls must resemble their support (places.resemblance)
    proximity = np.zeros((0, 0))
    trees = 0  # with a place to check: the forest's trees (the leaves kept per block)
    places = model.places
    if (
        cfg.descriptors
        and cfg.resemble > 0
        and places is not None
        and places.support_leaves is not None
        and places.forest is not None
    ):
        names = places.classes
        check = np.array([j for j, k in enumerate(names) if k in cfg.resemble_places], int)
        proximity = np.full((len(ranges), len(names)), np.inf)  # inf: not measured
        trees = len(places.forest.roots) if len(check) else 0
    for i in range(0, len(ranges), SCANS_PER_STEP):
        rows = slice(i, min(i + SCANS_PER_STEP, len(ranges)))
        block = ranges[rows]
        if model.places is None or not cfg.descriptors:
            scores = per_class(model, loglik(model, block, chunk) * model.temperature)
        else:
            x = features(
                ranges,
                model.laser,
                columns,
                along,
                cfg.context,
                rows,
                cfg.beside,
                poses,
                cfg.local_map,
                cfg.ahead(model.laser),
                cfg.opening,
                factor,
                cfg.reach_metres,
            )
            # each scan's leaf per tree, kept from the trees' walk for the resemblance check
            leaves = np.empty((len(x), trees), dtype=np.int32) if trees else None
            scores = model.places.log_proba(x, none=cfg.none_class, leaves=leaves)
            if leaves is not None and check is not None:
                measured = (scores[:, check].max(axis=1) >= np.log(RESEMBLE_SKIP)) | np.isin(
                    scores[:, : proximity.shape[1]].argmax(axis=1), check
                )
                which = np.flatnonzero(measured)
                proximity[rows][which] = model.places.proximity_of_leaves(leaves, check, which)
            if cfg.beam_term:
                beams = per_class(model, loglik(model, block, chunk) * model.temperature)
                scores = scores + cfg.beam_term * np.log(softmax(beams))
        out[i : i + len(block)] = scores
        if progress is not None:
            progress(len(block))
    if check is not None and len(check):  # the log's own calls are the reference: 2nd pass
        k = proximity.shape[1]
        out[:, :k] += resemblance(out, proximity, check, cfg.resemble)
    return out


def _laser_like(model: FeatureModel, ranges: np.ndarray) -> LaserGeometry:
    return replace(model.laser, beams=int(ranges.shape[1]))
