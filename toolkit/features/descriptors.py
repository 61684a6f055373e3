"""Scan descriptors that travel: what a place looks like wherever along it the robot stands.

The per-beam model compares beam k with beam k, so a corridor taught at one spot (a long view
ahead) does not look like the same corridor ten metres on. These descriptors are the
geometric features of Mozos, Stachniss and Burgard (ICRA 2005) and range histograms, each a
number per scan that changes little as the robot moves along a place:

- ranges: return fraction; mean and spread of the ranges and of their logarithms;
- range differences between neighbouring beams: mean, spread, and the share of jumps over
  0.5, 1.5 and 3 m (gaps: doorways, columns, the edges of a hall);
- the scan polygon (the origin and the beams' end points): log area, log perimeter,
  compactness 4 pi A / P^2; the end points' second moments: log of both axes of their
  ellipse and its elongation;
- a range histogram: the share of beams in 10 range bins and of no-returns;
- 12 sectors of 15 degrees: the mean log range, the no-return share (glass) and the spread of
  log ranges per sector, each for a sector and its mirror image (left / right) as the
  smaller and the larger of the two, so that a door on the left taught on the way out is
  the same door on the right on the way back; and the free width beside the robot (the
  sides' mean ranges summed).

Lengths beside the robot, the sectors' log ranges, the polygon's area and perimeter are in
units of the free width beside the laser (the nearest end points left and right within
`BESIDE` of the scan line, summed), which is a descriptor of its own: a door is a door in a
corridor of 2 m and of 3.5 m. `PLACE_DESCRIPTORS` leaves out what describes the view ahead
(the forward sectors, the range statistics and histogram, the polygon): that view is the
next place, not this one, and changes with every step (measured in the ablation).

No-returns and ranges beyond `CAP` count as `CAP` metres in the geometry. One compiled pass
per scan, in parallel over scans (`describe`: S x B ranges to S x D descriptors).
"""

from __future__ import annotations

import numba
import numpy as np

from toolkit.dataset import LaserGeometry

CAP = 20.0  # m: farther ranges (and no-returns) count as this in the geometry
HIST_EDGES = np.array([0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0])  # m, 10 bins
SECTORS = 12  # 15 degrees each over -90..90
GAPS = np.array([0.5, 1.5, 3.0])  # m: jumps between neighbouring beams
#: m: end points within this distance ahead or behind the laser are beside it. 1.0 before:
#: a door 0.5 m behind the laser still showed beside it, and half of the false doors and
#: windows were scans just outside their zone (development seeds 0-19: 0.2-0.5 alike on the
#: random worlds; 0.4 left the corridor scenario at 0.948, 0.45 and 0.5 at 0.957)
BESIDE = 0.45
#: m: the wider strip the open set's claims look at (`toolkit.features.places.log_claims`):
#: what surrounds a place, not where exactly its edge is
CLAIM_BESIDE = 1.0
CELL = 0.001  # m: the log and the histogram bin of a range are looked up on this grid
_SUMS = 14 + len(GAPS) + len(HIST_EDGES) + 2  # per-scan accumulators (see _accumulate)


def names() -> list[str]:
    """The descriptors' names, in column order."""
    out = [
        "return_fraction",
        "range_mean",
        "range_std",
        "log_range_mean",
        "log_range_std",
        "diff_mean",
        "diff_std",
        *(f"gaps_over_{g:g}m" for g in GAPS),
        "log_area",
        "log_perimeter",
        "compactness",
        "log_major_axis",
        "log_minor_axis",
        "elongation",
        *(
            f"hist_{lo:g}_{hi:g}m"
            for lo, hi in zip([0.0, *HIST_EDGES], [*HIST_EDGES, CAP], strict=True)
        ),
        "hist_no_return",
        "log_side_width",
    ]
    for what in ("beside_near", "beside_far", "beside_depth", "beside_count"):
        out += [f"{what}_min", f"{what}_max"]
    out.append("log_width_beside")
    for what in ("log_range", "no_return", "log_spread"):
        for k in range(SECTORS // 2):
            a = 90 - 15 * k
            out += [f"{what}_{a - 15}_{a}deg_min", f"{what}_{a - 15}_{a}deg_max"]
    return out + list(ABSOLUTE)


#: the reach beside the laser in metres (log), not in units of the free width: the nearer
#: side's nearest end point, the farther side's, and the farthest end point of either side
#: (a hall is metres deep beside the robot whether it opens on one side or both)
ABSOLUTE = ("beside_abs_near_min", "beside_abs_near_max", "beside_abs_far_max")

#: the descriptors that are logs of lengths across the path, in metres: the free width and
#: the reaches beside the laser, the side sectors' width, the end points' minor axis (a
#: corridor's spread across it). A corridor k times as wide (y -> k y) adds log k to each;
#: the others are ratios, shares or views ahead. A log is brought to another width by
#: adding it (`rescaled`), with no resampling of its beams (`Config.canonical_width`;
#: docs/journal/places.md, session 18: the minor axis added (c) 0.002 on four sets)
WIDTH_LIKE = ("log_side_width", "log_width_beside", *ABSOLUTE, "log_minor_axis")


#: the no-returns that see glass ahead of the place: the whole scan's return fraction and the
#: no-return share at 30-60 degrees reach a window 0.5-2 m before the robot is beside it
#: (docs/journal/places.md, session 14); the place's own no-returns are those at 60-90 degrees
#: the view ahead's range-histogram bins under 2 m: the share of a scan's beams ending near
#: the laser, which in a hall taught from 10 scans of one world is that hall's furniture of
#: walls, not the place's (`Config.view_ahead_near_bins`; session 29, thin29)
NEAR_BINS = ("hist_0_0.5m", "hist_0.5_1m", "hist_1_1.5m", "hist_1.5_2m")
GLASS_AHEAD = ("return_fraction", "no_return_30_45deg", "no_return_45_60deg")


def place_columns(absolute: bool = True, glass_ahead: bool = False) -> np.ndarray:
    """Indices of the descriptors the place classifier uses (all but the view ahead; without
    `absolute`, not the reach beside the laser in metres either; with `glass_ahead`, also
    the no-returns ahead, `GLASS_AHEAD`, as until session 13)."""
    ahead = ("0_15deg", "15_30deg", "range_mean", "range_std", "major", "area", "perimeter")
    return np.array(
        [
            i
            for i, n in enumerate(names())
            if not any(a in n for a in ahead)
            and not n.startswith("hist_")
            and (absolute or n not in ABSOLUTE)
            and (glass_ahead or not n.startswith(GLASS_AHEAD))
        ]
    )


def describe(ranges: np.ndarray, laser: LaserGeometry, strip: float = BESIDE) -> np.ndarray:
    """Descriptors (S x D float64) of scans (S x B, NaN = no return); what is beside the
    laser: the end points within `strip` metres ahead or behind it."""
    bearing = laser.angles + laser.yaw
    # sectors mirror each other exactly: (0, 15°] left is [-15°, 0) right (the beam straight
    # ahead counts on the left)
    ring = np.clip(np.ceil(np.abs(bearing) / (np.pi / SECTORS) - 1e-9) - 1, 0, SECTORS // 2 - 1)
    half = SECTORS // 2
    sector = np.where(bearing < 0, half - 1 - ring, half + ring).astype(np.int64)
    cells = np.arange(int(CAP / CELL) + 2) * CELL + CELL / 2
    log_of = np.log(np.maximum(cells, 0.01))
    bin_of = np.searchsorted(HIST_EDGES, cells, side="right").astype(np.int64)
    sums = np.empty((len(ranges), _SUMS))
    per_sector = np.empty((len(ranges), 4, SECTORS))
    beside = np.empty((len(ranges), 2, 3))
    _accumulate(
        np.ascontiguousarray(ranges, dtype=np.float32),
        np.cos(bearing),
        np.sin(bearing),
        sector,
        log_of,
        bin_of,
        GAPS,
        CAP,
        strip,
        sums,
        per_sector,
        beside,
    )
    out = np.empty((len(ranges), len(names())))
    _finish_compiled(sums, per_sector, beside, ranges.shape[1], out)
    return out


@numba.njit(parallel=True, cache=True)
def _accumulate(  # pragma: no cover - numba
    ranges: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    sector: np.ndarray,
    log_of: np.ndarray,
    bin_of: np.ndarray,
    gaps: np.ndarray,
    cap: float,
    near: float,
    sums: np.ndarray,
    per_sector: np.ndarray,
    beside: np.ndarray,
) -> None:
    """Per scan, the sums the descriptors are made of, in one pass over its beams: the sums
    in registers, the counts in the scan's rows of the outputs (no allocation per scan).
    `gaps` ascending: a beam counts once, at the largest gap it exceeds (summed up after)."""
    s_count, nb = ranges.shape
    n_gaps, n_bins = len(gaps), int(bin_of.max()) + 1
    inv_cell = 1.0 / CELL
    last = len(log_of) - 1
    hist = 14 + n_gaps
    for s in numba.prange(s_count):
        acc = sums[s]
        sec = per_sector[s]  # count, sum log, sum log^2, no-returns per sector
        acc[14:] = 0.0
        sec[:] = 0.0
        # per side (right, left): nearest, farthest |y|, count
        near0, far0, n0, near1, far1, n1 = cap, 0.0, 0.0, cap, 0.0, 0.0
        a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = a8 = a9 = a10 = a11 = a12 = a13 = 0.0
        px, py, prev = 0.0, 0.0, 0.0
        for b in range(nb):
            r = ranges[s, b]
            ok = r < cap and r > -np.inf  # finite and below the cap (np.isfinite: 25% slower)
            rc = r if ok else cap
            cell = min(int(rc * inv_cell), last)
            lr = log_of[cell]
            a0 += ok
            a1 += rc
            a2 += rc * rc
            a3 += lr
            a4 += lr * lr
            x, y = rc * cos[b], rc * sin[b]
            a9 += x
            a10 += y
            a11 += x * x
            a12 += y * y
            a13 += x * y
            if b > 0:
                d = abs(rc - prev)
                a5 += d
                a6 += d * d
                a7 += 0.5 * (px * y - x * py)  # area: fan of triangles from the origin
                a8 += np.sqrt((x - px) ** 2 + (y - py) ** 2)  # perimeter
                g = 0
                while g < n_gaps and d > gaps[g]:
                    g += 1
                if g > 0:
                    acc[13 + g] += 1.0
            else:
                a8 += rc  # from the origin to the first end point
            if ok:
                acc[hist + bin_of[cell]] += 1.0
            else:
                acc[hist + n_bins] += 1.0
            if abs(x) < near:  # beside the laser: how far the space reaches sideways
                ay = abs(y)
                if y > 0:
                    near1, far1, n1 = min(near1, ay), max(far1, ay), n1 + 1.0
                else:
                    near0, far0, n0 = min(near0, ay), max(far0, ay), n0 + 1.0
            j = sector[b]
            sec[0, j] += 1.0
            sec[1, j] += lr
            sec[2, j] += lr * lr
            sec[3, j] += not ok
            px, py, prev = x, y, rc
        a8 += prev  # back to the origin
        for g in range(n_gaps - 2, -1, -1):  # over the g-th gap: also over every larger one
            acc[14 + g] += acc[15 + g]
        acc[0], acc[1], acc[2], acc[3], acc[4], acc[5], acc[6] = a0, a1, a2, a3, a4, a5, a6
        acc[7], acc[8], acc[9], acc[10], acc[11], acc[12], acc[13] = a7, a8, a9, a10, a11, a12, a13
        beside[s, 0, 0], beside[s, 0, 1], beside[s, 0, 2] = near0, far0, n0
        beside[s, 1, 0], beside[s, 1, 1], beside[s, 1, 2] = near1, far1, n1


def _finish(sums: np.ndarray, per_sector: np.ndarray, beside: np.ndarray, beams: int) -> np.ndarray:
    """The descriptors from the accumulated sums, in numpy: the reference `describe`'s
    compiled finish (`_finish_compiled`) is tested equal to."""
    n = float(beams)
    ng, ne = len(GAPS), len(HIST_EDGES)

    def spread(total: np.ndarray, squares: np.ndarray, count: np.ndarray | float) -> np.ndarray:
        mean = total / np.maximum(count, 1.0)
        return np.sqrt(np.maximum(squares / np.maximum(count, 1.0) - mean * mean, 0.0))

    area = np.maximum(np.abs(sums[:, 7]), 1e-3)
    perimeter = np.maximum(sums[:, 8], 1e-3)
    mx, my = sums[:, 9] / n, sums[:, 10] / n
    cxx, cyy = sums[:, 11] / n - mx * mx, sums[:, 12] / n - my * my
    cxy = sums[:, 13] / n - mx * my
    half_trace, det = 0.5 * (cxx + cyy), cxx * cyy - cxy * cxy
    root = np.sqrt(np.maximum(half_trace**2 - det, 0.0))
    major, minor = np.maximum(half_trace + root, 1e-4), np.maximum(half_trace - root, 1e-4)
    near = np.log(np.maximum(beside[:, :, 0], 0.05))
    far = np.log(np.maximum(beside[:, :, 1], 0.05))
    width = np.log(np.exp(near).sum(axis=1))  # the free width beside the laser
    count, log_sum, log_sq, missing = (per_sector[:, i] for i in range(4))
    mean_log = log_sum / np.maximum(count, 1.0)
    cols = [
        sums[:, 0] / n,
        sums[:, 1] / n,
        spread(sums[:, 1], sums[:, 2], n),
        sums[:, 3] / n,
        spread(sums[:, 3], sums[:, 4], n),
        sums[:, 5] / (n - 1),
        spread(sums[:, 5], sums[:, 6], n - 1),
        *(sums[:, 14 + g] / (n - 1) for g in range(ng)),
        np.log(area),
        np.log(perimeter),
        4 * np.pi * area / perimeter**2,
        0.5 * np.log(major),
        0.5 * np.log(minor),
        np.sqrt(minor / major),
        *(sums[:, 14 + ng + k] / n for k in range(ne + 2)),
        np.log(np.exp(mean_log[:, 0]) + np.exp(mean_log[:, -1])),
    ]
    cols[names().index("log_area")] -= 2 * width  # in units of the width: scale-free
    cols[names().index("log_perimeter")] -= width
    near, far = near - width[:, None], far - width[:, None]
    for values in (near, far, far - near, np.log1p(beside[:, :, 2])):
        cols += [values.min(axis=1), values.max(axis=1)]
    cols.append(width)
    per = [
        mean_log - width[:, None],
        missing / np.maximum(count, 1.0),
        spread(log_sum, log_sq, count),
    ]
    for values in per:
        for k in range(SECTORS // 2):
            a, b = values[:, SECTORS - 1 - k], values[:, k]  # left and its mirror, right
            cols += [np.minimum(a, b), np.maximum(a, b)]
    near_m = np.log(np.maximum(beside[:, :, 0], 0.05))
    far_m = np.log(np.maximum(beside[:, :, 1], 0.05))
    cols += [near_m.min(axis=1), near_m.max(axis=1), far_m.max(axis=1)]
    return np.column_stack(cols)


@numba.njit(parallel=True, cache=True)
def _finish_compiled(  # pragma: no cover - numba
    sums: np.ndarray, per_sector: np.ndarray, beside: np.ndarray, beams: int, out: np.ndarray
) -> None:
    """`_finish` compiled, one scan per iteration in parallel (the same columns)."""
    n = float(beams)
    ng, nh = len(GAPS), len(HIST_EDGES) + 2
    half = SECTORS // 2
    for s in numba.prange(sums.shape[0]):
        a = sums[s]
        c = 0
        out[s, c] = a[0] / n
        mean = a[1] / n
        out[s, c + 1] = mean
        out[s, c + 2] = np.sqrt(max(a[2] / n - mean * mean, 0.0))
        mean = a[3] / n
        out[s, c + 3] = mean
        out[s, c + 4] = np.sqrt(max(a[4] / n - mean * mean, 0.0))
        mean = a[5] / (n - 1)
        out[s, c + 5] = mean
        out[s, c + 6] = np.sqrt(max(a[6] / (n - 1) - mean * mean, 0.0))
        c = 7
        for g in range(ng):
            out[s, c + g] = a[14 + g] / (n - 1)
        c += ng
        near0 = np.log(max(beside[s, 0, 0], 0.05))
        near1 = np.log(max(beside[s, 1, 0], 0.05))
        far0 = np.log(max(beside[s, 0, 1], 0.05))
        far1 = np.log(max(beside[s, 1, 1], 0.05))
        width = np.log(np.exp(near0) + np.exp(near1))
        area = max(abs(a[7]), 1e-3)
        perimeter = max(a[8], 1e-3)
        mx, my = a[9] / n, a[10] / n
        cxx, cyy, cxy = a[11] / n - mx * mx, a[12] / n - my * my, a[13] / n - mx * my
        half_trace, det = 0.5 * (cxx + cyy), cxx * cyy - cxy * cxy
        root = np.sqrt(max(half_trace * half_trace - det, 0.0))
        major, minor = max(half_trace + root, 1e-4), max(half_trace - root, 1e-4)
        out[s, c] = np.log(area) - 2 * width
        out[s, c + 1] = np.log(perimeter) - width
        out[s, c + 2] = 4 * np.pi * area / (perimeter * perimeter)
        out[s, c + 3] = 0.5 * np.log(major)
        out[s, c + 4] = 0.5 * np.log(minor)
        out[s, c + 5] = np.sqrt(minor / major)
        c += 6
        for k in range(nh):
            out[s, c + k] = a[14 + ng + k] / n
        c += nh
        first = per_sector[s, 1, 0] / max(per_sector[s, 0, 0], 1.0)
        last = per_sector[s, 1, SECTORS - 1] / max(per_sector[s, 0, SECTORS - 1], 1.0)
        out[s, c] = np.log(np.exp(first) + np.exp(last))
        c += 1
        near0, near1, far0, far1 = near0 - width, near1 - width, far0 - width, far1 - width
        pairs = (
            (near0, near1),
            (far0, far1),
            (far0 - near0, far1 - near1),
            (np.log1p(beside[s, 0, 2]), np.log1p(beside[s, 1, 2])),
        )
        for u, v in pairs:
            out[s, c] = min(u, v)
            out[s, c + 1] = max(u, v)
            c += 2
        out[s, c] = width
        c += 1
        for what in range(3):
            for k in range(half):
                vals = np.empty(2)
                for m, j in enumerate((SECTORS - 1 - k, k)):
                    count = max(per_sector[s, 0, j], 1.0)
                    mean_log = per_sector[s, 1, j] / count
                    if what == 0:
                        vals[m] = mean_log - width
                    elif what == 1:
                        vals[m] = per_sector[s, 3, j] / count
                    else:
                        vals[m] = np.sqrt(max(per_sector[s, 2, j] / count - mean_log**2, 0.0))
                out[s, c] = min(vals[0], vals[1])
                out[s, c + 1] = max(vals[0], vals[1])
                c += 2
        near0, near1 = np.log(max(beside[s, 0, 0], 0.05)), np.log(max(beside[s, 1, 0], 0.05))
        far0, far1 = np.log(max(beside[s, 0, 1], 0.05)), np.log(max(beside[s, 1, 1], 0.05))
        out[s, c] = min(near0, near1)
        out[s, c + 1] = max(near0, near1)
        out[s, c + 2] = max(far0, far1)


# ---------------------------------------------------------------- context along the path

#: m of path per scan assumed when there are no poses (the context window then counts scans)
STEP_WITHOUT_POSES = 0.1


def mozos_columns() -> np.ndarray:
    """Indices of the descriptors of Mozos, Stachniss and Burgard (2005) alone: the range
    statistics, the differences and gaps, the polygon, the ellipse and the histogram (the
    peer baseline: no sectors, nothing beside the laser)."""
    own = ("beside", "log_range_", "no_return_", "log_spread_", "log_width", "log_side")
    return np.array([i for i, n in enumerate(names()) if not n.startswith(own)])


def path_length(n: int, poses: np.ndarray | None) -> np.ndarray:
    """Per scan, the path travelled from the first scan (m; turning 1 rad counts as 1 m, as in
    the HMM); without poses (or their count differs), `STEP_WITHOUT_POSES` per scan."""
    if poses is None or len(poses) != n:
        return np.arange(n) * STEP_WITHOUT_POSES
    step = np.zeros(n)
    if n > 1:
        d = np.diff(poses[:, :2], axis=0)
        turn = np.abs(np.remainder(np.diff(poses[:, 2]) + np.pi, 2 * np.pi) - np.pi)
        step[1:] = np.nan_to_num(np.hypot(d[:, 0], d[:, 1]) + turn, nan=STEP_WITHOUT_POSES)
    return np.cumsum(step)


def context_windows(
    along: np.ndarray, half: float, rows: slice | None = None, ahead: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per scan (of `rows`, default all), the first and one-past-last index of the scans
    within `half` metres of path before it and `ahead` (default `half`) after it (itself
    included)."""
    at = along if rows is None else along[rows]
    lo = np.searchsorted(along, at - half, side="left")
    hi = np.searchsorted(along, at + (half if ahead is None else ahead), side="right")
    return lo, np.maximum(hi, lo + 1)


def context_ahead(context: float, strip: float, laser: LaserGeometry) -> float:
    """m of path the context window reaches ahead of a scan, so that its scans see `context`
    metres of path beside the laser either side. A scanner of 180 degrees or less sees
    nothing behind itself: each scan's strip beside the laser (`strip`) lies ahead of it, and
    a window reaching `context` ahead would see `context + strip` ahead but only `context`
    behind. Such a window called the scans up to 0.6 m before a door's zone (and 0.9 m before
    a window's) doors and windows (docs/journal/places.md, session 12). A scanner that sees behind
    itself gets the symmetric window."""
    bearing = np.abs(laser.angles + laser.yaw)
    if bearing.max() > np.pi / 2 + 1e-6:
        return context
    return max(context - strip, 0.0)


def with_context(
    x: np.ndarray, lo: np.ndarray, hi: np.ndarray, own: np.ndarray | None = None
) -> np.ndarray:
    """Descriptors `x[own]` (S x D; default: all rows) followed by their mean and spread over
    each scan's window of rows [lo, hi) (S x 3D): a place persists over several scans, and a door, a niche and the mouth
    of a side corridor differ in how long and how deep the gap beside the robot stays."""
    # running sums of centred values: less cancellation in the spread
    centre = x.mean(axis=0) if len(x) else np.zeros(x.shape[1])
    x = np.ascontiguousarray(x, dtype=np.float64)
    c1 = np.empty((len(x) + 1, x.shape[1]))
    c2 = np.empty_like(c1)
    _running_sums(x, centre, c1, c2)
    own = np.arange(len(lo)) if own is None else own
    out = np.empty((len(lo), 3 * x.shape[1]))
    _window_moments(x, c1, c2, lo, hi, own, centre, out)
    return out


#: descriptors whose running sums one thread keeps (`_running_sums`)
COLUMNS_PER_TASK = 8


@numba.njit(parallel=True, cache=True)
def _running_sums(  # pragma: no cover - numba
    x: np.ndarray, centre: np.ndarray, c1: np.ndarray, c2: np.ndarray
) -> None:
    """c1[i], c2[i]: the sums of x - centre and of its square over rows before i (as
    numpy's cumsum of them: row after row), in one pass, a group of columns per task."""
    n, d = x.shape
    for task in numba.prange((d + COLUMNS_PER_TASK - 1) // COLUMNS_PER_TASK):
        j0 = task * COLUMNS_PER_TASK
        j1 = min(j0 + COLUMNS_PER_TASK, d)
        for j in range(j0, j1):
            c1[0, j] = 0.0
            c2[0, j] = 0.0
        for i in range(n):
            for j in range(j0, j1):
                v = x[i, j] - centre[j]
                c1[i + 1, j] = c1[i, j] + v
                c2[i + 1, j] = c2[i, j] + v * v


@numba.njit(parallel=True, cache=True)
def _window_moments(  # pragma: no cover - numba
    x: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    own: np.ndarray,
    centre: np.ndarray,
    out: np.ndarray,
) -> None:
    """Per scan: its descriptors, their window mean and spread from the running sums."""
    d = x.shape[1]
    for s in numba.prange(len(lo)):
        a, b, i = lo[s], hi[s], own[s]
        count = float(b - a)
        for j in range(d):
            mean = (c1[b, j] - c1[a, j]) / count
            out[s, j] = x[i, j]
            out[s, d + j] = mean + centre[j]
            out[s, 2 * d + j] = np.sqrt(max((c2[b, j] - c2[a, j]) / count - mean * mean, 0.0))


def chosen_columns(
    view_ahead: bool = False,
    mozos: bool = False,
    absolute: bool = True,
    glass_ahead: bool = False,
    near_bins: bool = True,
) -> np.ndarray:
    """The descriptors a classifier uses: Mozos et al.'s alone, all (`near_bins` False: all
    but `NEAR_BINS`), or those of the place (`absolute`: with the reach beside the laser in
    metres; `glass_ahead`: with the no-returns ahead, `GLASS_AHEAD`)."""
    if mozos:
        return mozos_columns()
    if view_ahead:
        every = np.arange(len(names()))
        return every if near_bins else every[~np.isin(names(), NEAR_BINS)]
    return place_columns(absolute, glass_ahead)


def rescaled(x: np.ndarray, columns: np.ndarray, factor: float) -> np.ndarray:
    """Descriptors `columns` of scans (S x len(columns)) as those of the scans stretched
    across the path by `factor`: log `factor` added to the `WIDTH_LIKE` ones (in place).
    Why: a stretched scan is resampled, each beam drawn from another bearing, and that
    changes the differences, gaps and sectors of the taught world's own scans as much at a
    factor of 1.1 as of 2 (session 17); the widths alone carry the building's scale."""
    if factor != 1.0:
        for j in np.flatnonzero(np.isin(np.asarray(names())[columns], WIDTH_LIKE)):
            x[:, j] += np.log(factor)  # a column at a time: no copy of the whole block
    return x


def metres_columns(columns: np.ndarray) -> np.ndarray:
    """Positions in `columns` of the reach beside the laser in metres (`ABSOLUTE`)."""
    return np.flatnonzero(np.isin(np.asarray(names())[columns], ABSOLUTE))


def with_metres(x: np.ndarray, columns: np.ndarray, factor: float, metres: bool) -> np.ndarray:
    """`rescaled` descriptors, and with `metres` the reach beside the laser once more as
    measured (`Config.reach_metres`). Why: a room behind a door, a hall's depth do not
    scale with the corridor, so in another building the rescaled reach misplaces them
    (docs/journal/places.md, session 22)."""
    keep = x[:, metres_columns(columns)] if metres else None  # a copy, before the shift
    x = rescaled(x, columns, factor)
    return x if keep is None else np.hstack([x, keep])


def features(
    ranges: np.ndarray,
    laser: LaserGeometry,
    columns: np.ndarray,
    along: np.ndarray,
    context: float,
    rows: slice | None = None,
    strip: float = BESIDE,
    poses: np.ndarray | None = None,
    local: float = 0.0,
    ahead: float | None = None,
    gap: bool = False,
    factor: float = 1.0,
    metres: bool = False,
) -> np.ndarray:
    """The classifier's input for scans `rows` (default all) of a log: their descriptors
    `columns` and, with `context` > 0, the descriptors' mean and spread over the scans within
    `context` metres of path (`along`, see `path_length`) before and `ahead` (default
    `context`; see `context_ahead`) after each; only the scans those windows reach are
    described. `strip`: see `describe`. With `local` > 0, the descriptors of the local map of
    the scans within `local` metres of path (`local_map`, drawn by `poses`) follow; with
    `gap`, the opening beside the robot (`opening`). `factor`: the descriptors of the scans
    stretched across the path by this (`rescaled`); with `metres`, the reach beside the laser
    (`ABSOLUTE`) follows them once more as measured (`with_metres`)."""
    rows = rows or slice(0, len(ranges))
    if context <= 0:
        x = with_metres(describe(ranges[rows], laser, strip)[:, columns], columns, factor, metres)
    else:
        lo, hi = context_windows(along, context, rows, ahead)
        first, last = int(lo.min()), int(hi.max())
        own = np.arange(len(lo)) + (rows.start or 0) - first
        d = describe(ranges[first:last], laser, strip)[:, columns]
        x = with_context(with_metres(d, columns, factor, metres), lo - first, hi - first, own)
    if local > 0:
        x = np.hstack([x, local_map(ranges, laser, poses, along, local, rows)])
    if gap:
        x = np.hstack([x, opening(ranges, laser, poses, along, rows, strip)])
    return x


# ------------------------------------------------------- the local map along the path

#: m of path either side of a scan whose scans make its local map where the scans are too
#: far apart for the context (`Config.sparse_local_map`; development seeds 0-19 without the
#: context: 2 m against 1.5 and 3 m)
SPARSE_LOCAL_MAP = 2.0
#: scans of the local map's window drawn into it, evenly spaced along the window
LOCAL_SCANS = 5
#: every this many beams of each drawn scan (the map is dense enough with a third of them)
LOCAL_BEAM_STEP = 3
#: m ahead and behind the robot that the map's lateral profile covers, in bins of this
LOCAL_REACH, LOCAL_BIN = 2.0, 0.25
#: m: farther end points (and no-returns) are open space in the local map
LOCAL_FAR = 8.0
#: m: a side of a bin is open where its nearest end point is farther than this from the
#: path: beyond the wall of any corridor (1.6-4 m wide), into a room, a hall, a side corridor
LOCAL_OPEN = 3.0


def local_names() -> list[str]:
    """The local map's descriptors' names, in column order (`local_map`)."""
    out = []
    for side in ("open", "closed"):  # the more open side, the other
        for what in ("open_share", "open_run", "log_median", "log_max"):
            out.append(f"local_{side}_{what}")
    out += ["local_both_open", "local_log_width", "local_width_spread", "local_log_area"]
    for k in range(4):
        out += [f"local_polar_{22.5 * k:g}deg_{rank}" for rank in range(4)]
    return out


def local_map(
    ranges: np.ndarray,
    laser: LaserGeometry,
    poses: np.ndarray | None,
    along: np.ndarray,
    half: float,
    rows: slice | None = None,
) -> np.ndarray:
    """Descriptors of the place around each scan of `rows` (default all), not of one view:
    the end points of `LOCAL_SCANS` scans within `half` metres of path before and after it,
    drawn by their `poses` into the scan's own frame (without poses: overlaid where they
    are), described without regard to left and right or ahead and behind. Where the scans
    are too far apart for the context (its window would hold the neighbouring places'
    descriptors), their end points still show the walls and openings around the robot.
    Columns (`local_names`), in metres (log): per side, the more open one first, over bins
    of `LOCAL_BIN` along the path `LOCAL_REACH` ahead and behind: the share of bins whose
    nearest end point is beyond `LOCAL_OPEN` (open), the longest open run (m), the median
    and largest lateral reach; the share of bins open on both sides; the median and spread
    of the two-sided width; the area of the free space around the robot (from the nearest
    end point per 22.5° of bearing); and per 22.5° from the heading, the nearest end point
    in the four mirror images (ahead left and right, behind left and right), sorted."""
    beams = np.arange(0, laser.beams, LOCAL_BEAM_STEP)
    lateral, polar = _profiles(ranges, laser, poses, along, half, rows, beams, LOCAL_SCANS)
    return _local_finish(lateral, polar)


def _profiles(
    ranges: np.ndarray,
    laser: LaserGeometry,
    poses: np.ndarray | None,
    along: np.ndarray,
    half: float,
    rows: slice | None,
    beams: np.ndarray,
    scans: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The lateral profile (S, 2, bins) and the polar nearest end points (S, 4, 4) of the end
    points of `scans` scans (their `beams`) within `half` m of path of each scan of `rows`,
    drawn into its frame (`_local_points`): what `local_map` and `opening` describe."""
    rows = rows or slice(0, len(ranges))
    lo, hi = context_windows(along, half, rows)
    own = np.arange(rows.start or 0, (rows.start or 0) + len(lo))
    n = len(ranges)
    pose = np.zeros((n, 3)) if poses is None or len(poses) != n else np.nan_to_num(poses)
    bearing = laser.angles[beams] + laser.yaw
    nbin = round(2 * LOCAL_REACH / LOCAL_BIN)
    lateral = np.empty((len(lo), 2, nbin))
    polar = np.empty((len(lo), 4, 4))
    _local_points(
        np.ascontiguousarray(ranges, dtype=np.float32),
        beams,
        np.cos(bearing),
        np.sin(bearing),
        laser.x,
        laser.y,
        np.ascontiguousarray(pose, dtype=np.float64),
        lo,
        hi,
        own,
        scans,
        LOCAL_REACH,
        LOCAL_FAR,
        lateral,
        polar,
    )
    return lateral, polar


#: scans (evenly spaced over `LOCAL_REACH` of path either side, every beam) whose end
#: points show the side walls' openings beside the robot (`opening`)
OPENING_SCANS = 9
OPENING_NAMES = ("opening_run_more", "opening_run_other", "opening_log_depth")


def opening(
    ranges: np.ndarray,
    laser: LaserGeometry,
    poses: np.ndarray | None,
    along: np.ndarray,
    rows: slice | None = None,
    strip: float = BESIDE,
) -> np.ndarray:
    """The opening the robot stands beside, per side (`OPENING_NAMES`): the length along the
    path (m) of the run of open bins of the local map's lateral profile (`local_map`: nearest
    end point beyond `LOCAL_OPEN`) that meets the strip of `strip` m ahead and behind the
    laser, the longer side's first (0: a wall there), and the log of the median lateral
    reach in that run (the depth behind the gap; its wall's where there is none). A door is
    a gap of door width in one side wall right beside the robot with a room behind it; a
    side corridor's mouth or a hall's edge is metres wide, and a scan a metre past a door
    has a wall beside it: a single 180-degree scan sees neither the gap's length nor what
    is beside and behind the laser, the scans before and after it do."""
    every = np.arange(laser.beams)
    lateral, _ = _profiles(ranges, laser, poses, along, LOCAL_REACH, rows, every, OPENING_SCANS)
    nbin = lateral.shape[2]
    centre = (np.arange(nbin) + 0.5) * LOCAL_BIN - LOCAL_REACH
    near = np.abs(centre) < strip + LOCAL_BIN / 2  # the bins that meet the strip
    open_ = lateral > LOCAL_OPEN
    # each open bin's run: the index of the run's first bin (-1: a closed bin)
    first_bin = open_ & ~np.concatenate([np.zeros_like(open_[..., :1]), open_[..., :-1]], axis=2)
    label = np.where(
        open_, np.maximum.accumulate(np.where(first_bin, np.arange(nbin), -1), axis=2), -1
    )
    # ... and of its last bin: each open bin's run length is the bins from first to last
    last_bin = open_ & ~np.concatenate([open_[..., 1:], np.zeros_like(open_[..., :1])], axis=2)
    last = np.minimum.accumulate(np.where(last_bin, np.arange(nbin), nbin)[..., ::-1], axis=2)
    bins = last[..., ::-1] - label + 1
    length = np.where(open_ & near, bins * LOCAL_BIN, 0.0)  # (S, 2, N)
    best = length.argmax(axis=2)
    run = np.take_along_axis(length, best[..., None], axis=2)[..., 0]
    chosen = np.take_along_axis(label, best[..., None], axis=2)
    inside = np.where((run > 0)[..., None], label == chosen, near)  # the run, or the strip
    depth = np.log(np.maximum(np.nanmedian(np.where(inside, lateral, np.nan), axis=2), 0.05))
    more = (run[:, 1] > run[:, 0]) | ((run[:, 1] == run[:, 0]) & (depth[:, 1] > depth[:, 0]))
    i, m = np.arange(len(run)), more.astype(int)
    return np.column_stack([run[i, m], run[i, 1 - m], depth[i, m]])


def _local_finish(lateral: np.ndarray, polar: np.ndarray) -> np.ndarray:
    """The local map's descriptors from its nearest end points per side and bin along the
    path (S, 2, N) and per quadrant and 22.5° sector (S, 4, 4), in metres: a hall is as wide
    beside the robot in a building of narrow corridors as of wide ones."""
    open_ = lateral > LOCAL_OPEN
    run = np.zeros(open_.shape[:2])
    best = np.zeros(open_.shape[:2])
    for b in range(open_.shape[2]):  # a dozen bins: vectorised over scans and sides
        run = np.where(open_[:, :, b], run + 1, 0)
        best = np.maximum(best, run)
    log_reach = np.log(np.maximum(lateral, 0.05))
    per_side = np.stack(
        [open_.mean(axis=2), best * LOCAL_BIN, np.median(log_reach, axis=2), log_reach.max(axis=2)],
        axis=2,
    )  # (S, 2 sides, 4)
    first = (per_side[:, 1, 0] > per_side[:, 0, 0]) | (
        (per_side[:, 1, 0] == per_side[:, 0, 0]) & (per_side[:, 1, 2] > per_side[:, 0, 2])
    )
    rows = np.arange(len(lateral))
    more, other = per_side[rows, first.astype(int)], per_side[rows, 1 - first.astype(int)]
    two = np.log(np.maximum(lateral.sum(axis=1), 0.05))
    cols = [*more.T, *other.T]
    cols.append((open_[:, 0] & open_[:, 1]).mean(axis=1))
    cols += [np.median(two, axis=1), two.std(axis=1)]
    cols.append(np.log(0.5 * (polar**2).sum(axis=(1, 2)) * (np.pi / 8)))
    ranked = np.sort(np.log(np.maximum(polar, 0.05)), axis=1)
    for k in range(4):
        cols += [ranked[:, r, k] for r in range(4)]
    return np.column_stack(cols)


@numba.njit(parallel=True, cache=True)
def _local_points(  # pragma: no cover - numba
    ranges: np.ndarray,
    beams: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    lx: float,
    ly: float,
    poses: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    own: np.ndarray,
    k_scans: int,
    reach: float,
    far: float,
    lateral: np.ndarray,
    polar: np.ndarray,
) -> None:
    """Per scan `own[i]`: the end points of `k_scans` scans of its window [lo, hi), in its
    frame; the nearest |y| per bin along the path and side, the nearest distance per
    quadrant and 22.5° sector (no end point: `far`)."""
    nbin = lateral.shape[2]
    t1, t3 = np.tan(np.pi / 8), np.tan(3 * np.pi / 8)
    scale = nbin / (2 * reach)
    for i in numba.prange(len(own)):
        lateral[i] = far
        polar[i] = far
        s = own[i]
        x0, y0, th0 = poses[s, 0], poses[s, 1], poses[s, 2]
        c0, s0 = np.cos(th0), np.sin(th0)
        a, n = lo[i], hi[i] - lo[i]
        m_count = min(k_scans, n)
        for m in range(m_count):
            j = a + (m * (n - 1)) // max(m_count - 1, 1)
            dx, dy = poses[j, 0] - x0, poses[j, 1] - y0
            tx, ty = c0 * dx + s0 * dy, -s0 * dx + c0 * dy
            dth = poses[j, 2] - th0
            cj, sj = np.cos(dth), np.sin(dth)
            for k in range(len(beams)):
                r = ranges[j, beams[k]]
                if not (r < far and r > 0.0):  # no return (NaN) or far: open space
                    continue
                px, py = lx + r * cos[k], ly + r * sin[k]
                qx, qy = tx + cj * px - sj * py, ty + sj * px + cj * py
                ax, ay = abs(qx), abs(qy)
                if ax < reach:
                    b = min(int((qx + reach) * scale), nbin - 1)
                    side = 1 if qy > 0 else 0
                    if ay < lateral[i, side, b]:
                        lateral[i, side, b] = ay
                d = np.sqrt(qx * qx + qy * qy)
                quad = 2 * (qx < 0) + (qy > 0)
                sec = 0 if ay < t1 * ax else (1 if ay < ax else (2 if ay < t3 * ax else 3))
                if d < polar[i, quad, sec]:
                    polar[i, quad, sec] = d
