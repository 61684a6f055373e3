"""Scan matching for laser logs in the paper's spirit: O(B) per scan pair, no tree, no search.

For each pair of consecutive scans (prev, cur):

1. Seed: the relative pose of the current laser in the previous laser's frame, from odometry.
2. Correspondence by beam order (polar/projective association): every current return is
   moved into the previous frame and projected onto the previous scan's beams by its
   bearing, angle -> fractional beam index; the two neighbouring previous returns give the
   surface line it should lie on (no nearest-neighbour search: one division per point).
3. The paper's Gaussian step (Eq. 3-6) on those correspondences: the shift is the weighted
   mean of the displacements measured along each line's normal (Eq. 3 with matrix weights
   w_i n_i n_i^T, i.e. weighted point-to-line normal equations, with rotation), their
   weighted variance (Eq. 4), and re-weighting that lowers the weight of returns that
   changed (Eq. 5-6), capped; at most `iterations` rounds, fewer once a pair has settled.
   The rounds settle on the mode nearest their start, keeping about a tenth of the seed's
   error; when the estimate lands far from the seed (`restart_turn`, `restart_shift`) the
   rounds run again from it, which removes the heading bias odometry drift would leave.
4. Motion model: the correction to odometry is bounded (`max_correction`, `max_turn`).
5. Degeneracy: the 2 x 2 translation information (the normal matrix, rotation marginalised)
   has a small eigenvalue where the scan cannot fix a direction (a featureless corridor);
   along that eigenvector the estimate keeps the odometry instead of inventing motion.
6. Covariance of each estimate: sigma^2 times the inverse information on the observed
   directions, the odometry's variance on the others.

Pairs are independent given odometry, so a whole log is matched at once (`match_pairs`,
numba-parallel over pairs); `StreamMatcher` feeds one scan at a time through the same
float32 kernel with constant working memory and gives the same poses.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal, ParamSpec, TypeVar

import numba as nb
import numpy as np

from toolkit import se2
from toolkit.align import se2_jit
from toolkit.dataset import LaserGeometry

P = ParamSpec("P")
R = TypeVar("R")

Variant = Literal["text", "paper"]
ProbeAxis = Literal["heading", "motion"]


@dataclass(frozen=True)
class MatchConfig:
    """Scan matcher parameters; lengths in m, angles in rad."""

    iterations: int = 10  # most Gaussian rounds per pair (a pair stops once settled)
    max_correction: float = 0.5  # motion model: largest translation error of odometry per step
    max_turn: float = 1.0  # motion model: largest rotation error of odometry per step
    gate: float = 0.5  # residuals beyond this are never evidence
    jump: float = 0.1  # neighbouring returns further apart than this (plus what the range
    # and the steepest incidence allow) are not one surface
    sigma_min: float = 0.01  # floor of the residual spread (the sensor's range noise)
    degenerate_ratio: float = 0.02  # translation info eigenvalue ratio below which odometry rules
    min_information: float = 8.0  # ... or below this (in returns seen head-on)
    min_points: int = 20  # fewer usable correspondences: keep the odometry
    odometry_sigma: tuple[float, float] = (0.05, 0.02)  # m, rad: odometry's per-step spread
    max_incidence: float = 1.31  # rad (75°): lines seen more obliquely are depth edges
    variant: Variant = "text"  # Eq. 6 as the text says; "paper" as printed
    rescue_step: float = 0.1  # heading ladder step when odometry is far off (0: no rescue)
    rescue_below: float = 0.3  # ... tried when the agreeing weight is below this share of returns
    keyframe_distance: float = 0.3  # match against a keyframe until odometry moved this far
    keyframe_angle: float = 0.2  # ... or turned this much (0, 0: consecutive scans)
    settle_shift: float = 1e-3  # a pair has settled once a round moves it less than this
    settle_turn: float = 1e-4  # ... and turns it less than this
    restart_turn: float = 0.01  # estimate this far from odometry (rad; < 0: never) ...
    restart_shift: float = 0.05  # ... or this far (m): refine again, started from it
    probe_axis: ProbeAxis = "heading"  # without odometry, the forward probe (whether the fit
    # observes the motion) along the heading (a vehicle) or along the predicted motion
    # (motion: a hand-held scanner whose heading sways off its path; expert)
    heading_map: int = 0  # without odometry, > 0: each scan's heading fitted (its translation
    # held) to a local map of this many recent keyframes (`toolkit.slam.heading`; 0: off)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class PairMatches:
    """Per pair k (scan k-1 -> scan k): relative laser pose, covariance and diagnostics."""

    pose: np.ndarray  # P x 3 (x, y, theta) of the current laser in the previous laser frame
    covariance: np.ndarray  # P x 3 x 3
    sigma: np.ndarray  # P: residual spread (m) at the end
    used: np.ndarray  # P: correspondences that carried weight
    degenerate: np.ndarray  # P: 0 none, 1 one translation direction from odometry, 2 all
    agreement: np.ndarray  # P: share of the current scan's returns that fit the estimate
    doubt: np.ndarray  # P: heading (rad) from the estimate to a rival fit that fits more, or 0

    def __len__(self) -> int:
        return len(self.pose)

    def take(self, part: slice) -> PairMatches:
        """The pairs in `part`."""
        return PairMatches(*(getattr(self, f.name)[part] for f in fields(self)))

    @classmethod
    def concat(cls, parts: list[PairMatches]) -> PairMatches:
        """`parts`' pairs, in order, as one PairMatches."""
        names = [f.name for f in fields(cls)]
        return cls(*(np.concatenate([getattr(p, name) for p in parts]) for name in names))

    @classmethod
    def empty(cls, n: int) -> PairMatches:
        return cls(
            np.zeros((n, 3)),
            np.zeros((n, 3, 3)),
            np.zeros(n),
            np.zeros(n, np.int32),
            np.zeros(n, np.int8),
            np.zeros(n),
            np.zeros(n),
        )


# ---------------------------------------------------------------- the kernel


@nb.njit(cache=True, nogil=True, inline="always")
def _bearing(y: float, x: float) -> float:
    """atan2 to ~1e-5 rad (a polynomial): only picks the beam, the residual stays exact.
    Branch-free (selects), so a loop of it vectorises; NaN in, NaN out."""
    ax = abs(x)
    ay = abs(y)
    big = max(ax, ay)
    z = min(ax, ay) / (big if big > 0.0 else 1.0)
    z2 = z * z
    a = z * (
        0.99986605 + z2 * (-0.33029950 + z2 * (0.18014100 + z2 * (-0.08513300 + z2 * 0.02083510)))
    )
    a = 1.5707963267948966 - a if ay > ax else a
    a = 3.141592653589793 - a if x < 0.0 else a
    a = -a if y < 0.0 else a
    return a if x == x else x


_POW2_NEG = np.array([2.0**-k for k in range(64)])  # 2^-k, the exponent part of _exp_neg


@nb.njit(cache=True, nogil=True, inline="always")
def _exp_neg(x: float) -> float:
    """exp(-x) for x >= 0 to ~1e-9 relative (0 beyond 40): a weight, not a result; the
    library exp is a third of a round's cost. 2^-n from a table, 2^-f (|f| <= 1/2) by a
    degree-7 Taylor polynomial of exp(-f ln 2)."""
    if not x < 40.0:
        return 0.0
    y = x * 1.4426950408889634  # x / ln 2
    n = int(y + 0.5)
    t = (y - n) * -0.6931471805599453  # |t| <= ln 2 / 2
    p = 1.0 + t * (
        1.0
        + t
        * (
            0.5
            + t
            * (
                1.0 / 6.0
                + t * (1.0 / 24.0 + t * (1.0 / 120.0 + t * (1.0 / 720.0 + t * (1.0 / 5040.0))))
            )
        )
    )
    return float(p * _POW2_NEG[n])


# kernel parameter slots: `MatchConfig` (and the beam step) as one float64 array for numba,
# written by `_params` and read by these names only
(
    _P_ITERATIONS,
    _P_MAX_CORRECTION,
    _P_MAX_TURN,
    _P_GATE,
    _P_JUMP,
    _P_SIGMA_MIN,
    _P_DEGENERATE_RATIO,
    _P_MIN_POINTS,
    _P_ODOMETRY_SIGMA_T,
    _P_ODOMETRY_SIGMA_R,
    _P_PAPER,  # 1.0: Eq. 6 as printed
    _P_COS_MAX_INCIDENCE,
    _P_MIN_INFORMATION,
    _P_RESCUE_STEP,
    _P_RESCUE_BELOW,
    _P_BEAM_STEP,  # |angle increment| of the laser
    _P_SETTLE_SHIFT,
    _P_SETTLE_TURN,
    _P_RESTART_TURN,
    _P_RESTART_SHIFT,
) = range(20)
_PARAMS = 20

# state slots of one refinement, kept in a small float64 array
_TX, _TY, _TH, _VAR, _USED, _SW, _DEG, _UX, _UY = range(9)
_H = 9  # h00 h01 h02 h11 h12 h22 at 9..14
_SCORE = 15  # returns that agree at a fixed scale (comparable between starts)
_STATE = 16


@nb.njit(cache=True, nogil=True)
def _prepare(
    prev: np.ndarray,
    cur: np.ndarray,
    cos_a: np.ndarray,
    sin_a: np.ndarray,
    params: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    nx: np.ndarray,
    ny: np.ndarray,
    cx: np.ndarray,
    cy: np.ndarray,
) -> int:
    """Both scans' returns and the previous scan's surface lines; returns the valid count."""
    jump = params[_P_JUMP]
    min_incidence = params[_P_COS_MAX_INCIDENCE]
    spread = params[_P_BEAM_STEP] / max(min_incidence, 1e-3)  # beam step / cos(max incidence)
    nbeams = prev.shape[0]
    valid = 0
    for i in range(nbeams):
        r = prev[i]
        px[i] = r * cos_a[i]
        py[i] = r * sin_a[i]
        r = cur[i]
        cx[i] = r * cos_a[i]
        cy[i] = r * sin_a[i]
        if r == r:
            valid += 1
    for i in range(nbeams - 1):
        dx = px[i + 1] - px[i]
        dy = py[i + 1] - py[i]
        d2 = dx * dx + dy * dy
        # one surface: neighbours no further apart than a surface at the steepest accepted
        # incidence puts them (grows with range), plus `jump`
        reach = jump + 0.5 * (prev[i] + prev[i + 1]) * spread
        ok = d2 < reach * reach and d2 > 1e-12  # NaN compares False: no line
        if ok:
            inv = np.float32(1.0) / np.float32(math.sqrt(d2))
            nx[i] = -dy * inv
            ny[i] = dx * inv
            # a line seen at grazing incidence is a depth edge's chord, not a surface
            mx = px[i] + px[i + 1]
            my = py[i] + py[i + 1]
            ok = abs(nx[i] * mx + ny[i] * my) >= min_incidence * math.sqrt(mx * mx + my * my)
        if not ok:
            nx[i] = np.nan
            ny[i] = np.nan
    nx[nbeams - 1] = np.nan
    return valid


# fast reciprocals, fused multiply-adds, fast exp/trig; not "nnan" (NaN marks no return) and
# not "reassoc" (the batch and streaming forms must sum in the same order)
@nb.njit(cache=True, nogil=True, fastmath={"arcp", "contract", "afn"})
def _refine(
    start: np.ndarray,
    seed: np.ndarray,
    angle_min: float,
    angle_inc: float,
    params: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    nx: np.ndarray,
    ny: np.ndarray,
    cx: np.ndarray,
    cy: np.ndarray,
    fb: np.ndarray,
    state: np.ndarray,
) -> None:
    """Gaussian rounds (Eq. 3-6 on point-to-line correspondences) from pose `start`, bounded
    around the odometry `seed`; the result goes to `state`."""
    iterations = int(params[_P_ITERATIONS])
    max_corr = params[_P_MAX_CORRECTION]
    max_turn = params[_P_MAX_TURN]
    gate = params[_P_GATE]
    var_min = params[_P_SIGMA_MIN] * params[_P_SIGMA_MIN]
    ratio = params[_P_DEGENERATE_RATIO]
    min_points = params[_P_MIN_POINTS]
    paper = params[_P_PAPER] > 0.5
    min_info = params[_P_MIN_INFORMATION]
    settle_t = params[_P_SETTLE_SHIFT]
    settle_r = params[_P_SETTLE_TURN]
    nbeams = px.shape[0]
    inv_inc = 1.0 / angle_inc

    tx, ty, th = start[0], start[1], start[2]
    var = gate * gate
    h00 = h01 = h02 = h11 = h12 = h22 = 0.0
    used = 0.0
    sw = 0.0
    score = 0.0
    agree = 1.0 / (2.0 * 9.0 * var_min)
    degenerate = 0
    ux, uy = 1.0, 0.0  # the observed translation direction when one is degenerate
    converged = False
    for it in range(iterations + 1):
        last = it == iterations or converged
        c = np.float32(math.cos(th))
        s = np.float32(math.sin(th))
        ftx = np.float32(tx)
        fty = np.float32(ty)
        cap = 1.0 / (2.0 * var)
        h00 = h01 = h02 = h11 = h12 = h22 = 0.0
        g0 = g1 = g2 = 0.0
        sw = 0.0
        swe = 0.0
        used = 0.0
        # every return's fractional beam index in the previous scan, in one branch-free
        # (vectorised) pass; the gathers and sums below then need no trig
        for j in range(nbeams):
            ax = c * cx[j] - s * cy[j]
            ay = s * cx[j] + c * cy[j]
            fb[j] = (_bearing(ay + fty, ax + ftx) - angle_min) * inv_inc
        for j in range(nbeams):
            f = fb[j]
            if not (f >= 0.0 and f < nbeams - 1):  # NaN (no return) fails too
                continue
            ax = c * cx[j] - s * cy[j]  # the return's offset from the current laser, rotated
            ay = s * cx[j] + c * cy[j]
            qx = ax + ftx
            qy = ay + fty
            i = int(f)
            n0 = nx[i]
            if math.isnan(n0):
                continue
            n1 = ny[i]
            e = n0 * (qx - px[i]) + n1 * (qy - py[i])
            if abs(e) > gate:
                continue
            e2 = float(e) * float(e)
            if it == 0:
                w = 1.0
            elif paper:  # Eq. 6 as printed: weight times squared residual, capped
                w = min(e2 / var, 1.0)
            else:  # the text: changed returns lose weight
                w = _exp_neg(e2 * cap)
            if w < 1e-6:
                continue
            used += 1.0
            jr = float(n1 * ax - n0 * ay)
            h00 += w * n0 * n0
            h01 += w * n0 * n1
            h02 += w * n0 * jr
            h11 += w * n1 * n1
            h12 += w * n1 * jr
            h22 += w * jr * jr
            g0 += w * n0 * e
            g1 += w * n1 * e
            g2 += w * jr * e
            sw += w
            swe += w * e2
            if last:
                score += _exp_neg(e2 * agree)
        if sw <= 0.0 or used < min_points:
            tx, ty, th = seed[0], seed[1], seed[2]
            degenerate = 2
            score = 0.0
            break
        var = max(swe / sw, var_min)  # Eq. 4
        if last:
            break  # the last round only measures the spread and information at the estimate
        # translation information with the rotation marginalised (Schur complement)
        if h22 > 1e-12:
            a = h00 - h02 * h02 / h22
            b = h01 - h02 * h12 / h22
            d = h11 - h12 * h12 / h22
        else:
            a, b, d = h00, h01, h11
        half_tr = 0.5 * (a + d)
        disc = math.sqrt(max(0.25 * (a - d) * (a - d) + b * b, 0.0))
        lam_max = half_tr + disc
        lam_min = half_tr - disc
        if lam_max < min_info:
            degenerate = 2
        elif lam_min < ratio * lam_max or lam_min < min_info:
            degenerate = 1
            if abs(b) > 1e-12:
                ux, uy = lam_max - d, b
            elif a >= d:
                ux, uy = 1.0, 0.0
            else:
                ux, uy = 0.0, 1.0
            norm = math.sqrt(ux * ux + uy * uy)
            ux /= norm
            uy /= norm
        else:
            degenerate = 0
        # Gauss-Newton step on the observed directions only
        if degenerate == 0:
            det = (
                h00 * (h11 * h22 - h12 * h12)
                - h01 * (h01 * h22 - h12 * h02)
                + h02 * (h01 * h12 - h11 * h02)
            )
            if abs(det) < 1e-18:
                break
            i00 = (h11 * h22 - h12 * h12) / det
            i01 = (h02 * h12 - h01 * h22) / det
            i02 = (h01 * h12 - h02 * h11) / det
            i11 = (h00 * h22 - h02 * h02) / det
            i12 = (h02 * h01 - h00 * h12) / det
            i22 = (h00 * h11 - h01 * h01) / det
            dx = -(i00 * g0 + i01 * g1 + i02 * g2)
            dy = -(i01 * g0 + i11 * g1 + i12 * g2)
            dt = -(i02 * g0 + i12 * g1 + i22 * g2)
        elif degenerate == 1:  # translation only along u, plus rotation
            huu = ux * (h00 * ux + h01 * uy) + uy * (h01 * ux + h11 * uy)
            hur = ux * h02 + uy * h12
            gu = ux * g0 + uy * g1
            det = huu * h22 - hur * hur
            if abs(det) < 1e-18:
                break
            su = -(h22 * gu - hur * g2) / det
            dt = -(huu * g2 - hur * gu) / det
            dx = su * ux
            dy = su * uy
        else:  # rotation only
            dx = dy = 0.0
            dt = -g2 / h22 if h22 > 1e-12 else 0.0
        tx += dx
        ty += dy
        th += dt
        # settled: one more round to measure (the same numbers a longer run would give)
        converged = it >= 1 and abs(dx) < settle_t and abs(dy) < settle_t and abs(dt) < settle_r
        # motion model: odometry is wrong by a bounded amount
        ex = tx - seed[0]
        ey = ty - seed[1]
        if degenerate == 1:  # along the unobserved direction, the odometry
            along = ex * ux + ey * uy
            ex, ey = along * ux, along * uy
        elif degenerate == 2:
            ex = ey = 0.0
        err = math.sqrt(ex * ex + ey * ey)
        if err > max_corr:
            ex *= max_corr / err
            ey *= max_corr / err
        tx = seed[0] + ex
        ty = seed[1] + ey
        th = seed[2] + min(max(th - seed[2], -max_turn), max_turn)
    state[_TX] = tx
    state[_TY] = ty
    state[_TH] = th
    state[_VAR] = var
    state[_USED] = used
    state[_SW] = sw
    state[_SCORE] = score
    state[_DEG] = degenerate
    state[_UX] = ux
    state[_UY] = uy
    state[_H + 0] = h00
    state[_H + 1] = h01
    state[_H + 2] = h02
    state[_H + 3] = h11
    state[_H + 4] = h12
    state[_H + 5] = h22


@nb.njit(cache=True, nogil=True)
def _covariance(state: np.ndarray, params: np.ndarray, out_cov: np.ndarray) -> int:
    """var * H^-1 on what the scan observed, the odometry's variance elsewhere."""
    odo_var_t = params[_P_ODOMETRY_SIGMA_T] * params[_P_ODOMETRY_SIGMA_T]
    odo_var_r = params[_P_ODOMETRY_SIGMA_R] * params[_P_ODOMETRY_SIGMA_R]
    var = state[_VAR]
    degenerate = int(state[_DEG])
    ux, uy = state[_UX], state[_UY]
    h00, h01, h02, h11, h12, h22 = state[_H : _H + 6]
    for r in range(3):
        for k in range(3):
            out_cov[r, k] = 0.0
    if degenerate == 0:
        det = (
            h00 * (h11 * h22 - h12 * h12)
            - h01 * (h01 * h22 - h12 * h02)
            + h02 * (h01 * h12 - h11 * h02)
        )
        if det > 1e-18:
            out_cov[0, 0] = var * (h11 * h22 - h12 * h12) / det
            out_cov[0, 1] = out_cov[1, 0] = var * (h02 * h12 - h01 * h22) / det
            out_cov[0, 2] = out_cov[2, 0] = var * (h01 * h12 - h02 * h11) / det
            out_cov[1, 1] = var * (h00 * h22 - h02 * h02) / det
            out_cov[1, 2] = out_cov[2, 1] = var * (h02 * h01 - h00 * h12) / det
            out_cov[2, 2] = var * (h00 * h11 - h01 * h01) / det
            return 0
        degenerate = 2
    if degenerate == 1:
        huu = ux * (h00 * ux + h01 * uy) + uy * (h01 * ux + h11 * uy)
        hur = ux * h02 + uy * h12
        det = huu * h22 - hur * hur
        if det > 1e-18:
            cuu = var * h22 / det
            crr = var * huu / det
            cur = -var * hur / det
            vx, vy = -uy, ux
            out_cov[0, 0] = cuu * ux * ux + odo_var_t * vx * vx
            out_cov[0, 1] = out_cov[1, 0] = cuu * ux * uy + odo_var_t * vx * vy
            out_cov[1, 1] = cuu * uy * uy + odo_var_t * vy * vy
            out_cov[0, 2] = out_cov[2, 0] = cur * ux
            out_cov[1, 2] = out_cov[2, 1] = cur * uy
            out_cov[2, 2] = crr
            return 1
    out_cov[0, 0] = out_cov[1, 1] = odo_var_t
    out_cov[2, 2] = odo_var_r
    return 2


@nb.njit(cache=True, nogil=True)
def _match_pair(
    prev: np.ndarray,
    cur: np.ndarray,
    cos_a: np.ndarray,
    sin_a: np.ndarray,
    angle_min: float,
    angle_inc: float,
    seed: np.ndarray,
    params: np.ndarray,
    out_pose: np.ndarray,
    out_cov: np.ndarray,
    out_stats: np.ndarray,
    work: np.ndarray,
) -> None:
    """Match one pair. `work` is a 7 x B float32 scratch array (no allocation per pair).

    Refines from the odometry first. If too few returns then agree (odometry off by more
    than the correspondences reach: a wheel slip), restarts from a ladder of headings
    within the motion model and keeps the start whose result most returns agree with (and
    polishes it). Otherwise, if the estimate lies far from the odometry, refines once more
    from it (see the module notes).
    """
    px, py, nx, ny, cx, cy, fb = work[0], work[1], work[2], work[3], work[4], work[5], work[6]
    valid = _prepare(prev, cur, cos_a, sin_a, params, px, py, nx, ny, cx, cy)
    state = np.empty(_STATE)
    best = np.empty(_STATE)
    start = np.empty(3)
    start[:] = seed[:3]
    _refine(start, seed, angle_min, angle_inc, params, px, py, nx, ny, cx, cy, fb, best)
    rescue_step = params[_P_RESCUE_STEP]
    rescued = False
    if rescue_step > 0.0 and best[_SCORE] < params[_P_RESCUE_BELOW] * valid:
        max_turn = params[_P_MAX_TURN]
        steps = int(max_turn / rescue_step)
        for k in range(1, steps + 1):
            for sign in (-1.0, 1.0):
                start[2] = seed[2] + sign * k * rescue_step
                _refine(
                    start, seed, angle_min, angle_inc, params, px, py, nx, ny, cx, cy, fb, state
                )
                if state[_SCORE] > 1.5 * best[_SCORE]:
                    best[:] = state
                    rescued = True
        if rescued:  # polish: more rounds from the chosen start
            start[0], start[1], start[2] = best[_TX], best[_TY], best[_TH]
            _refine(start, seed, angle_min, angle_inc, params, px, py, nx, ny, cx, cy, fb, state)
            if state[_SCORE] >= best[_SCORE]:
                best[:] = state
    # The rounds settle on the mode nearest their start: about a tenth of the odometry's
    # error survives (a heading bias that piles up over a log). A second run, started
    # afresh (uniform weights, wide spread) from the estimate, leaves a tenth of that.
    rt = params[_P_RESTART_TURN]
    rs = params[_P_RESTART_SHIFT]
    if not rescued and rt >= 0.0 and best[_DEG] < 2:
        moved = math.hypot(best[_TX] - seed[0], best[_TY] - seed[1])
        if abs(best[_TH] - seed[2]) > rt or moved > rs:
            start[0], start[1], start[2] = best[_TX], best[_TY], best[_TH]
            _refine(start, seed, angle_min, angle_inc, params, px, py, nx, ny, cx, cy, fb, state)
            best[:] = state
    degenerate = _covariance(best, params, out_cov)
    out_pose[0] = best[_TX]
    out_pose[1] = best[_TY]
    out_pose[2] = se2_jit.wrap(best[_TH])
    out_stats[0] = math.sqrt(best[_VAR])
    out_stats[1] = best[_USED]
    out_stats[2] = degenerate
    out_stats[3] = best[_SCORE] / max(valid, 1)


_CHUNKS = 512  # pieces of a log's pairs for the threads (8 or more pairs each at 4,000)


@nb.njit(cache=True, parallel=True)
def _match_all(
    ranges: np.ndarray,
    ref: np.ndarray,
    first: int,
    cos_a: np.ndarray,
    sin_a: np.ndarray,
    angle_min: float,
    angle_inc: float,
    seeds: np.ndarray,
    params: np.ndarray,
    out_pose: np.ndarray,
    out_cov: np.ndarray,
    out_stats: np.ndarray,
) -> None:
    """Pairs (ref[k], first+k+1) of `ranges` for every k, in parallel chunks of pairs.

    Many small chunks, handed out one at a time (`match_pairs` sets numba's parallel chunk
    size to 1): on a shared machine a thread whose core is busy elsewhere takes fewer
    chunks instead of holding the others at the end (static halves ran slower on 2 threads
    than on 1 under load)."""
    npairs = seeds.shape[0]
    nbeams = ranges.shape[1]
    nchunks = max(1, min(npairs, _CHUNKS))
    for chunk in nb.prange(nchunks):
        work = np.empty((7, nbeams), dtype=np.float32)
        lo = chunk * npairs // nchunks
        hi = (chunk + 1) * npairs // nchunks
        for k in range(lo, hi):
            _match_pair(
                ranges[ref[k]],
                ranges[first + k + 1],
                cos_a,
                sin_a,
                angle_min,
                angle_inc,
                seeds[k],
                params,
                out_pose[k],
                out_cov[k],
                out_stats[k],
                work,
            )


def _params(config: MatchConfig, laser: LaserGeometry) -> np.ndarray:
    """The kernels' parameter array (slots `_P_*`)."""
    c = config
    values = {
        _P_ITERATIONS: c.iterations,
        _P_MAX_CORRECTION: c.max_correction,
        _P_MAX_TURN: c.max_turn,
        _P_GATE: c.gate,
        _P_JUMP: c.jump,
        _P_SIGMA_MIN: c.sigma_min,
        _P_DEGENERATE_RATIO: c.degenerate_ratio,
        _P_MIN_POINTS: c.min_points,
        _P_ODOMETRY_SIGMA_T: c.odometry_sigma[0],
        _P_ODOMETRY_SIGMA_R: c.odometry_sigma[1],
        _P_PAPER: 1.0 if c.variant == "paper" else 0.0,
        _P_COS_MAX_INCIDENCE: math.cos(c.max_incidence),
        _P_MIN_INFORMATION: c.min_information,
        _P_RESCUE_STEP: c.rescue_step,
        _P_RESCUE_BELOW: c.rescue_below,
        _P_BEAM_STEP: abs(laser.angle_increment),
        _P_SETTLE_SHIFT: c.settle_shift,
        _P_SETTLE_TURN: c.settle_turn,
        _P_RESTART_TURN: c.restart_turn,
        _P_RESTART_SHIFT: c.restart_shift,
    }
    params = np.full(_PARAMS, np.nan)
    params[list(values)] = list(values.values())
    return params


def _tables(laser: LaserGeometry) -> tuple[np.ndarray, np.ndarray]:
    a = laser.angles
    return np.cos(a).astype(np.float32), np.sin(a).astype(np.float32)


def keyframes(odometry: np.ndarray, distance: float, angle: float) -> np.ndarray:
    """Reference scan of every scan (S,), chosen from odometry alone: each scan is matched
    against the last keyframe; a scan becomes the next keyframe once the odometry has moved
    `distance` or turned `angle` since the current one. ref[0] = 0; 0 and 0 give
    consecutive pairs (ref[k] = k - 1)."""
    return _keyframes(np.ascontiguousarray(odometry, dtype=np.float64), distance, angle)


@nb.njit(cache=True)
def _keyframes(odo: np.ndarray, distance: float, angle: float) -> np.ndarray:
    n = odo.shape[0]
    ref = np.zeros(n, dtype=np.int64)
    key = 0
    for k in range(1, n):
        ref[k] = key
        if se2_jit.is_keyframe(odo[k], odo[key], distance, angle):
            key = k
    return ref


def match_pairs(
    ranges: np.ndarray,
    seeds: np.ndarray,
    laser: LaserGeometry,
    config: MatchConfig | None = None,
    ref: np.ndarray | None = None,
    chunk: int = 65_536,
    progress: Callable[[int], object] | None = None,
) -> PairMatches:
    """Match every scan k >= 1 of `ranges` (S x B) against scan ref[k] (default k - 1).

    `seeds[k-1]` is the odometry's pose of laser k in the frame of laser ref[k] (see
    `toolkit.se2.laser_motion`). Pairs are independent given the seeds: all are matched at once, in
    parallel, in chunks of `chunk` pairs so the working memory stays bounded (and the result does
    not depend on `chunk`); `progress(m)` is called after each chunk of m pairs.
    """
    ranges = np.ascontiguousarray(ranges, dtype=np.float32)
    n = max(len(ranges) - 1, 0)
    refs = pair_refs(ref, len(ranges))
    if np.shape(seeds) != (n, 3):
        raise ValueError(f"seeds {np.shape(seeds)} do not match {n} scan pairs")
    return _matched(ranges, refs[1:], 1, seeds, laser, config, chunk, progress)


def match_scan_pairs(
    refs: np.ndarray,
    scans: np.ndarray,
    seeds: np.ndarray,
    laser: LaserGeometry,
    config: MatchConfig | None = None,
) -> PairMatches:
    """Match each scan of `scans` (P x B) against the one of `refs` (P x B) in the same row,
    `seeds[k]` the pose of laser `scans[k]` in the frame of laser `refs[k]`: pairs that are
    not consecutive scans of one log (`match_pairs` matches every scan of its array)."""
    if np.shape(refs) != np.shape(scans):
        raise ValueError(f"refs {np.shape(refs)} and scans {np.shape(scans)} differ")
    if np.shape(seeds) != (len(scans), 3):
        raise ValueError(f"seeds {np.shape(seeds)} do not match {len(scans)} scan pairs")
    ranges = np.concatenate([refs, scans]).astype(np.float32, copy=False)
    count = len(scans)
    return _matched(ranges, np.arange(count, dtype=np.int64), count, seeds, laser, config)


def _matched(
    ranges: np.ndarray,
    refs: np.ndarray,
    start: int,
    seeds: np.ndarray,
    laser: LaserGeometry,
    config: MatchConfig | None,
    chunk: int = 65_536,
    progress: Callable[[int], object] | None = None,
) -> PairMatches:
    """Pair k: scan `start + k` of `ranges` against scan `refs[k]`, by `seeds[k]`; in chunks
    of `chunk` pairs, `progress(m)` after each."""
    config = config or MatchConfig()
    ranges = np.ascontiguousarray(ranges, dtype=np.float32)
    seeds = np.ascontiguousarray(seeds, dtype=np.float64)
    n = len(seeds)
    if ranges.shape[1:] != (laser.beams,):
        raise ValueError(f"ranges have {ranges.shape[1:]} beams, the laser {laser.beams}")
    out = PairMatches.empty(n)
    stats = np.zeros((n, 4))
    cos_a, sin_a = _tables(laser)
    params = _params(config, laser)
    with nb.parallel_chunksize(1):
        for lo in range(0, n, chunk):
            hi = min(lo + chunk, n)
            _match_all(
                ranges,
                refs[lo:hi],
                start + lo - 1,
                cos_a,
                sin_a,
                float(laser.angle_min),
                float(laser.angle_increment),
                seeds[lo:hi],
                params,
                out.pose[lo:hi],
                out.covariance[lo:hi],
                stats[lo:hi],
            )
            if progress is not None:
                progress(hi - lo)
    out.sigma[:] = stats[:, 0]
    out.used[:] = stats[:, 1]
    out.degenerate[:] = stats[:, 2]
    out.agreement[:] = stats[:, 3]
    return out


def pair_refs(ref: np.ndarray | None, n: int) -> np.ndarray:
    """The reference scan of each of `n` scans (`ref`, checked; default: the previous one)."""
    if ref is None:
        return np.maximum(np.arange(n, dtype=np.int64) - 1, 0)
    refs = np.ascontiguousarray(ref, dtype=np.int64)
    if refs.shape != (n,) or (n > 1 and not ((refs[1:] >= 0) & (refs[1:] < np.arange(1, n))).all()):
        raise ValueError("ref must give every scan k >= 1 an earlier scan")
    return refs


class StreamMatcher:
    """The matcher one scan at a time, for a robot: float32 scans, constant working memory.

    Give it each scan with the odometry's pose at that scan; it returns the corrected robot
    pose. It keeps the keyframe scan (B float32), a 7 x B float32 work array and the beam
    angle tables: about 40 B bytes in all, whatever the log's length (7.6 KB at 181 beams).
    Keyframes, seeds, the kernel and the composition are those of the batch form
    (`match_pairs` with `keyframes`, composed by `toolkit.poses`), so the poses are the
    same.
    """

    def __init__(self, laser: LaserGeometry, config: MatchConfig | None = None) -> None:
        self.laser = laser
        self.config = config or MatchConfig()
        self._params = _params(self.config, laser)
        self._cos, self._sin = _tables(laser)
        self._key_scan = np.full(laser.beams, np.nan, dtype=np.float32)
        self._key_odometry = np.zeros(3)
        self._key_pose = np.zeros(3)
        self._started = False
        self._work = np.empty((7, laser.beams), dtype=np.float32)
        self.pose = np.zeros(3)  # relative pose of the last pair (laser frame)
        self.covariance = np.zeros((3, 3))
        self.stats = np.zeros(4)  # sigma, correspondences used, degenerate, agreement
        self.keyed = False  # whether the last scan pushed became the keyframe

    @property
    def working_bytes(self) -> int:
        """Bytes the matcher keeps between scans (keyframe scan, work arrays, tables)."""
        arrays = (self._key_scan, self._work, self._cos, self._sin, self._params)
        return sum(a.nbytes for a in arrays) + 8 * (3 + 3 + 3 + 3 + 9 + 3)

    def _scan(self, ranges: np.ndarray) -> np.ndarray:
        scan = np.asarray(ranges, dtype=np.float32)
        if scan.shape != (self.laser.beams,):
            raise ValueError(f"a scan of {self.laser.beams} beams expected, got {scan.shape}")
        return np.ascontiguousarray(scan)

    def _match(
        self,
        scan: np.ndarray,
        odo: np.ndarray,
        out_pose: np.ndarray,
        out_cov: np.ndarray,
        out_stats: np.ndarray,
    ) -> np.ndarray:
        """`scan` matched against the keyframe, seeded by the odometry's pose `odo`; the
        kernel's results go to the out arrays; returns the robot pose."""
        robot_seed = se2.between(self._key_odometry[None], odo[None])
        seed = np.ascontiguousarray(se2.laser_motion(robot_seed, self.laser)[0])
        _match_pair(
            self._key_scan,
            scan,
            self._cos,
            self._sin,
            float(self.laser.angle_min),
            float(self.laser.angle_increment),
            seed,
            self._params,
            out_pose,
            out_cov,
            out_stats,
            self._work,
        )
        step = se2.robot_motion(out_pose[None], self.laser)[0]
        pose = np.empty(3)
        se2_jit.compose_into(self._key_pose, step, pose)
        return pose

    def probe(self, ranges: np.ndarray, odometry: np.ndarray) -> np.ndarray:
        """The robot pose `push` would return for this scan and odometry, without taking the
        scan: no keyframe change, `pose`, `covariance` and `stats` untouched."""
        if not self._started:
            raise ValueError("probe needs a keyframe: push a scan first")
        odo = np.asarray(odometry, dtype=np.float64).reshape(3)
        return self._match(self._scan(ranges), odo, np.empty(3), np.empty((3, 3)), np.empty(4))

    def _checked(self, scan: np.ndarray, odo: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """The robot pose `push` keeps for `scan`, fitted to `pose` from the odometry `odo`:
        `pose` (a subclass may fit the scan again, `toolkit.slam.motion.MotionMatcher`)."""
        return pose

    def push(self, ranges: np.ndarray, odometry: np.ndarray) -> np.ndarray:
        """Take the next scan and the odometry's robot pose at it; return the robot pose."""
        scan = self._scan(ranges)
        odo = np.asarray(odometry, dtype=np.float64).reshape(3)
        if not self._started:
            self._started = True
            self._key_scan[:] = scan
            self._key_odometry[:] = odo
            self._key_pose[:] = odo
            self.keyed = True
            return odo.copy()
        pose = self._match(scan, odo, self.pose, self.covariance, self.stats)
        pose = self._checked(scan, odo, pose)
        cfg = self.config
        self.keyed = se2_jit.is_keyframe(
            odo, self._key_odometry, cfg.keyframe_distance, cfg.keyframe_angle
        )
        if self.keyed:
            self._key_scan[:] = scan
            self._key_odometry[:] = odo
            self._key_pose[:] = pose
        return pose


def scan_points(ranges: np.ndarray, laser: LaserGeometry) -> np.ndarray:
    """Returns of one scan in the laser frame, B x 2 (NaN where there is none)."""
    a = laser.angles
    r = np.asarray(ranges, dtype=np.float64)
    return np.column_stack([r * np.cos(a), r * np.sin(a)])
