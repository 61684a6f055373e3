"""Taught scans of the other side's kind: copies of the training log in which the side of
the path that is less open is opened (the more open side mirrored onto it) or closed (a
wall along the path at the log's usual distance).

Why: a place is taught by about ten scans at one spot, and what lies on the far side of the
path there is that spot's accident. A random world's hall opens on one side of its
corridor or on both; taught with one kind and met with the other, the hall was found in
0.12 and 0.00 of its scans (docs/journal/places.md, session 4). Both copies keep what is on the
more open side of the path (the place's own opening) and vary the other side. They are
whole logs, so the context along the path is described on the copied neighbours too.
The default learns both (`Config.augment_closed`, `augment_open`). The opened ones cost
the same world's runs with session 11's context window; with the window that sees as far
ahead as behind (session 12) they were the best row on every seed set, and are on since
session 13 (docs/places.md).
"""

from __future__ import annotations

import numpy as np

from toolkit import se2
from toolkit.dataset import LaserGeometry

LATERAL = np.sin(np.radians(30.0))  # beams at 30-150 degrees either side decide the sides
#: a copy whose side beams' log ranges differ from the scan's by less than this (mean over
#: the beams at 30-150 degrees) is the scan again, not a place of the other kind: left out
#: (development seeds 0-19: 0 cost (a) 0.009 and (b) 0.018; 0.15 / 0.3 / 0.5 gave (c) 0.844
#: / 0.847 / 0.833 and (b) 0.912 / 0.921 / 0.925; 0.5 kept (a) and (b) as they were)
CHANGED = 0.5


def changed(ranges: np.ndarray, copy: np.ndarray, laser: LaserGeometry) -> np.ndarray:
    """Per scan, whether its copy differs from it by `CHANGED` or more (mean absolute
    difference of log range over the beams at 30-150 degrees; a no-return: 20 m)."""
    side = np.abs(np.sin(laser.angles)) >= LATERAL
    diff = np.abs(_log_range(ranges[:, side]) - _log_range(copy[:, side]))
    return np.asarray(diff.mean(axis=1) >= CHANGED)


def differs(ranges: np.ndarray, copy: np.ndarray) -> np.ndarray:
    """Per scan, whether its copy differs from it in any beam (a no-return equal to a
    no-return): `changed` without its threshold, for a copy kept however little it moved."""
    same = (copy == ranges) | (np.isnan(copy) & np.isnan(ranges))
    return np.asarray(~np.all(same, axis=1))


def mirror_index(laser: LaserGeometry) -> np.ndarray:
    """Per beam, the beam at the opposite bearing (-angle), or itself where the scan has no
    beam there."""
    angles = laser.angles
    j = np.rint((-angles - laser.angle_min) / laser.angle_increment).astype(np.int64)
    ok = (j >= 0) & (j < len(angles))
    return np.where(ok, j, np.arange(len(angles)))


def opened(ranges: np.ndarray, laser: LaserGeometry) -> np.ndarray:
    """Each scan with both sides as open as the more open one: per beam, the farther of its
    range and its mirror beam's (a no-return is farthest)."""
    r = np.asarray(ranges, dtype=np.float32)
    m = r[:, mirror_index(laser)]
    out = np.fmax(r, m)
    out[np.isnan(r) | np.isnan(m)] = np.nan
    return out


def closed(ranges: np.ndarray, laser: LaserGeometry, wall: float | None = None) -> np.ndarray:
    """Each scan with its less open side walled: a wall along the path at `wall` m (default
    `usual_wall`), nearer returns kept (r = min(r, wall / |sin angle|) on that side)."""
    r = np.asarray(ranges, dtype=np.float32)
    wall = usual_wall(r, laser) if wall is None else wall
    return _walled(r, laser, closed_left(r, laser), wall)


def closed_left(ranges: np.ndarray, laser: LaserGeometry) -> np.ndarray:
    """Per scan, whether `closed` walls its left side (the left is the less open: a
    no-return counts as 20 m)."""
    r = np.asarray(ranges, dtype=np.float32)
    return np.asarray(_openness(r, laser.angles, True) <= _openness(r, laser.angles, False))


def _walled(r: np.ndarray, laser: LaserGeometry, left: np.ndarray, wall: float) -> np.ndarray:
    """Each scan with its left side (`left`, per scan) or else its right walled at `wall`
    m along the path, nearer returns kept (r = min(r, wall / |sin angle|) on that side)."""
    angles = laser.angles
    side = np.where(left[:, None], angles[None, :] > 0, angles[None, :] < 0)
    reach = (wall / np.maximum(np.abs(np.sin(angles)), 1e-6)).astype(np.float32)
    near = np.where(np.isnan(r), reach[None, :], np.fmin(r, reach[None, :]))
    return np.where(side, near, r).astype(np.float32)


#: m beyond a side's nearest end point (its wall) from which a return is seen through an
#: opening in it (`across_left`): a door's room is 3-4 m deep, a box along the wall 0.2-0.6
DEPTH = 1.0


def across_left(ranges: np.ndarray, laser: LaserGeometry) -> np.ndarray:
    """Per scan, whether its left side is the one across the path from its place's opening:
    the side with the smaller share of beams (at 30-150 degrees) returned from `DEPTH` m or
    more beyond the side's nearest end point (what is seen through an opening; a no-return,
    glass, is not counted); where the shares are equal, `closed_left`'s side. `closed_left`
    takes the less open side by the mean log range, a no-return as 20 m: a door across the
    path from a window, or in the nearer wall of a wide corridor, is walled itself
    (docs/journal/places.md, session 24)."""
    r = np.asarray(ranges, dtype=np.float32)
    left, right = (_beyond(r, laser.angles, s) for s in (True, False))
    return np.asarray(np.where(left == right, closed_left(r, laser), left < right))


def glass_across(ranges: np.ndarray, laser: LaserGeometry) -> np.ndarray:
    """Per scan, whether the side across from its opening (`across_left`) gives a no-return
    at 30-150 degrees: glass across the path (or nothing within range)."""
    r = np.asarray(ranges, dtype=np.float32)
    angles = laser.angles
    left = across_left(r, laser)
    across = np.where(left[:, None], angles[None, :] > 0, angles[None, :] < 0)
    beside = across & (np.abs(np.sin(angles)) >= LATERAL)[None, :]
    return np.asarray((beside & np.isnan(r)).any(axis=1))


def _beyond(r: np.ndarray, angles: np.ndarray, left: bool) -> np.ndarray:
    """Per scan, the share of one side's beams at 30-150 degrees returned from `DEPTH` m or
    more beyond the side's nearest lateral distance to an end point."""
    side = ((angles > 0) == left) & (np.abs(np.sin(angles)) >= LATERAL)
    lateral = np.abs(r[:, side] * np.sin(angles[side])[None, :])  # a no-return: NaN
    with np.errstate(all="ignore"):
        wall = np.nanmin(lateral, axis=1, initial=np.inf)
    return np.asarray((lateral >= wall[:, None] + DEPTH).mean(axis=1))


#: degrees from normal incidence within which `glazed`'s pane returns (the simulator's
#: `glass_normal_deg`: a pane seen obliquely gives no return)
PANE_NORMAL = 15.0
#: m along the path either side of the laser that `glazed`'s window spans (the random
#: worlds' windows are 1.5-10 m long)
PANE_HALF = 2.0
#: m nearer than a side's wall that `glazed` still takes for the wall (noise, the path's sway)
PANE_SLACK = 0.25


def walled_across(
    ranges: np.ndarray, laser: LaserGeometry, wall: float | None = None
) -> np.ndarray:
    """Each scan with the side across from its opening (`across_left`: glass is not an
    opening) walled at `wall` m (default `usual_wall`), nearer returns kept: a door across
    the path from a window, taught, as the door alone. Where that is the side `closed`
    walls, the copy is `closed`'s."""
    r = np.asarray(ranges, dtype=np.float32)
    wall = usual_wall(r, laser) if wall is None else wall
    return _walled(r, laser, across_left(r, laser), wall)


def glazed(ranges: np.ndarray, laser: LaserGeometry) -> np.ndarray:
    """Each scan with a window across from its opening (`across_left`): on that side, a
    beam that meets the side's wall (its median lateral distance to an end point, within
    `PANE_SLACK` m) or gives no return, where the wall lies within `PANE_HALF` m along the
    path, gets no return but within `PANE_NORMAL` degrees of normal incidence (glass);
    nearer returns kept. A door taught with a wall across the path, met across from a
    window, was called window (docs/journal/places.md, session 24)."""
    r = np.asarray(ranges, dtype=np.float32)
    angles = laser.angles
    left = across_left(r, laser)
    sin = np.maximum(np.abs(np.sin(angles)), 1e-6)
    lateral = np.abs(r * np.sin(angles)[None, :])
    across = np.where(left[:, None], angles[None, :] > 0, angles[None, :] < 0)
    beside = across & (sin >= LATERAL)[None, :]
    with np.errstate(all="ignore"):
        wall = np.nanmedian(np.where(beside, lateral, np.nan), axis=1)  # NaN: all glass
    wall = np.where(np.isfinite(wall), wall, usual_wall(r, laser))[:, None]
    pane = beside & (wall * np.abs(np.cos(angles))[None, :] / sin[None, :] <= PANE_HALF)
    meets = np.isnan(r) | (lateral >= wall - PANE_SLACK)
    oblique = np.abs(np.cos(angles)) > np.sin(np.radians(PANE_NORMAL))
    return np.where(pane & meets & oblique[None, :], np.nan, r).astype(np.float32)


def glazable(ranges: np.ndarray, laser: LaserGeometry) -> np.ndarray:
    """Per scan, whether an opening is seen through one side and nothing through the other
    (`DEPTH`): a place across from a plain wall, which `glazed` turns into a window."""
    r = np.asarray(ranges, dtype=np.float32)
    left, right = (_beyond(r, laser.angles, s) for s in (True, False))
    return np.asarray((np.minimum(left, right) == 0) & (np.maximum(left, right) > 0))


def usual_wall(ranges: np.ndarray, laser: LaserGeometry) -> float:
    """The median over the log's scans and sides of the nearest lateral distance to an end
    point (|y| of beams at 30-150 degrees): how far the path usually runs from a wall."""
    values = np.concatenate(_nearest_beside(ranges, laser))
    values = values[np.isfinite(values)]
    return float(np.median(values)) if len(values) else 1.0


def _nearest_beside(ranges: np.ndarray, laser: LaserGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Per scan, the nearest lateral distance to an end point (|y| of beams at 30-150
    degrees) on the right and on the left (NaN where that side has none)."""
    angles = laser.angles
    lateral = np.abs(ranges * np.sin(angles)[None, :])
    lateral = np.where(np.abs(np.sin(angles))[None, :] >= LATERAL, lateral, np.nan)
    with np.errstate(all="ignore"):
        right, left = (
            np.nanmin(np.where((angles > 0) == s, lateral, np.nan), axis=1) for s in (0, 1)
        )
    return right, left


def _openness(r: np.ndarray, angles: np.ndarray, left: bool) -> np.ndarray:
    """Per scan, the mean log range of one side's beams at 30-150 degrees (a no-return or a
    range beyond 20 m: 20 m)."""
    side = ((angles > 0) == left) & (np.abs(np.sin(angles)) >= LATERAL)
    return np.asarray(_log_range(r[:, side]).mean(axis=1))


def _log_range(r: np.ndarray) -> np.ndarray:
    """log(range + 0.1 m), a no-return or a range beyond 20 m taken as 20 m."""
    return np.asarray(np.log(np.fmin(np.nan_to_num(r, nan=20.0), 20.0) + 0.1))


def stretched(ranges: np.ndarray, laser: LaserGeometry, factor: float) -> np.ndarray:
    """Each scan with what it sees stretched across the path by `factor` (y -> factor * y in
    the laser's frame, x along the path kept): a corridor `factor` times as wide, its doors'
    and windows' length along the path unchanged. Per beam, the scan's range at the bearing
    that lands there, interpolated between its two beams where they see one surface (ranges
    within 10 % of each other), else the nearer beam's; a range beyond the laser's
    `range_max` is a no-return (NaN)."""
    r = np.asarray(ranges, dtype=np.float32)
    b = laser.angles
    a = np.arctan2(np.sin(b), factor * np.cos(b))  # the source bearing of each output beam
    f = (a - laser.angle_min) / laser.angle_increment
    ok = (f > -0.5) & (f < len(b) - 0.5)
    lo = np.clip(np.floor(f).astype(np.int64), 0, len(b) - 1)
    hi = np.clip(lo + 1, 0, len(b) - 1)
    w = np.clip(f - lo, 0.0, 1.0).astype(np.float32)
    r0, r1 = r[:, lo], r[:, hi]
    near = np.where(w[None, :] < 0.5, r0, r1)
    with np.errstate(invalid="ignore"):
        smooth = np.abs(r0 - r1) <= 0.1 * np.fmin(r0, r1)
    src = np.where(smooth, (1.0 - w)[None, :] * r0 + w[None, :] * r1, near)
    x, y = src * np.cos(a)[None, :], src * np.sin(a)[None, :]
    out = np.hypot(x, factor * y).astype(np.float32)
    out[:, ~ok] = np.nan
    with np.errstate(invalid="ignore"):
        out[out > laser.range_max] = np.nan
    return np.asarray(out, dtype=np.float32)


def usual_width(ranges: np.ndarray, laser: LaserGeometry) -> float:
    """The median over the log's scans of the free width across the path: the nearest
    lateral distance to an end point (|y| of beams at 30-150 degrees) on the left plus that
    on the right (scans with both sides seen); where the robot runs off the centre line
    does not move it."""
    right, left = _nearest_beside(ranges, laser)
    width = right + left
    width = width[np.isfinite(width)]
    return float(np.median(width)) if len(width) else 2.0


def width_factor(ranges: np.ndarray, laser: LaserGeometry, width: float) -> float:
    """The stretch across the path that brings the log's usual free width (`usual_width`,
    on at most about 20,000 of its scans) to `width` m (1 for an empty log)."""
    r = np.asarray(ranges, dtype=np.float32)
    sample = r[:: max(1, len(r) // 20000)]
    return width / max(usual_width(sample, laser), 0.2) if len(r) else 1.0


def to_width(ranges: np.ndarray, laser: LaserGeometry, width: float) -> np.ndarray:
    """The log stretched across the path (`stretched`) by `width_factor`: every building's
    corridor at one width, for descriptors that measure in metres
    (`Config.canonical_width` with `canonical_how` "stretch")."""
    r = np.asarray(ranges, dtype=np.float32)
    return stretched(r, laser, width_factor(r, laser, width)) if len(r) else r


def canonical(
    ranges: np.ndarray, laser: LaserGeometry, width: float, how: str
) -> tuple[np.ndarray, float]:
    """The log as its descriptors see it at a usual free width of `width` m
    (`Config.canonical_width`; 0: as measured): with `how` "stretch", the log stretched
    (`to_width`) and a factor of 1; with "rescale", the log as it is and the factor by which
    `descriptors.rescaled` shifts its widths. Learning and applying a model resolve it alike."""
    if width <= 0:
        return ranges, 1.0
    if how == "stretch":
        return to_width(ranges, laser, width), 1.0
    return ranges, width_factor(ranges, laser, width)


#: m ahead of (or behind) the laser beyond which `ended` closes what lies past the side
#: walls: a scan at a hall's end sees half a hall (docs/journal/places.md, session 22)
END_AHEAD = 0.5


def ended(
    ranges: np.ndarray,
    laser: LaserGeometry,
    ahead: bool = True,
    distance: float = END_AHEAD,
    wall: float | None = None,
) -> np.ndarray:
    """Each scan as at a place's end: beyond `distance` m ahead of the laser (behind it,
    `ahead` False) what lies past the side walls is closed, on both sides, by the side walls
    at `wall` m (default `usual_wall`) and an end wall across the opening at `distance`;
    nearer returns kept. A beam past the wall line beyond the end is stopped at the wall
    line (r = wall / |sin|), one past it short of the end at the end wall (r = distance /
    cos); one that leaves the other way is kept. The corridor ahead and behind stays open.
    Why: a place taught at its middle, met at its end, looks half like it (a hall's end,
    a corner's edge: session 22's false doors)."""
    r = np.asarray(ranges, dtype=np.float32)
    wall = usual_wall(r, laser) if wall is None else wall
    sin = np.maximum(np.abs(np.sin(laser.angles)), 1e-6)
    cos = np.cos(laser.angles) * (1.0 if ahead else -1.0)  # along the closed direction
    cross = wall * cos / sin  # where along the path the beam crosses the wall line
    with np.errstate(divide="ignore"):
        end = np.where(cos > 0, distance / np.maximum(cos, 1e-9), np.inf)
    reach = np.where(cross > distance, wall / sin, end).astype(np.float32)
    return np.asarray(np.minimum(r, reach[None, :]), dtype=np.float32)  # a no-return kept


#: m ahead of (or behind) the laser from which `started` leaves the place open: the
#: corridor just outside a hall, where door22 found a sixth of transfer's false doors
#: (docs/journal/places.md, session 23)
START_AHEAD = 0.5


def started(
    ranges: np.ndarray,
    laser: LaserGeometry,
    ahead: bool = True,
    distance: float = START_AHEAD,
    wall: float | None = None,
) -> np.ndarray:
    """Each scan as from the corridor just outside its place: what lies past the side walls
    short of `distance` m ahead of the laser (behind it, `ahead` False) is closed by the
    side walls at `wall` m (default `usual_wall`), what lies beyond is kept (the place
    starts there). A beam that crosses the wall line short of the start stops there (r =
    wall / |sin|, a no-return too where that is within `range_max`); one that crosses it
    beyond keeps its range (the place's far wall is as far across the path from there). `ended`'s complement: a place taught at its middle, the
    corridor before it (or after it) met. Why: the corridor by a hall fell to the door."""
    r = np.asarray(ranges, dtype=np.float32)
    wall = usual_wall(r, laser) if wall is None else wall
    sin = np.maximum(np.abs(np.sin(laser.angles)), 1e-6)
    cos = np.cos(laser.angles) * (1.0 if ahead else -1.0)  # along the open direction
    cross = wall * cos / sin  # where along the path the beam crosses the wall line
    side = wall / sin  # a no-return short of the start is the wall, unless out of range
    reach = np.where((cross < distance) & (side <= laser.range_max), side, np.inf)
    return np.asarray(np.fmin(r, reach.astype(np.float32)[None, :]), dtype=np.float32)


#: m: the cell of the grid a taught span's returns are drawn into for `turned_views` (the
#: rays march a quarter cell at a time)
TURN_CELL = 0.05
#: cells of `TURN_CELL` per side of the coarser cell in which `turned_views` records what
#: the source beams crossed (beams 1 degree apart are 0.17 m apart at 10 m)
TURN_SEEN = 4
#: m: how far `turned_views` renders a beam; one that meets nothing seen within it is a
#: no-return (a longer range changes the log-range descriptors little)
TURN_FAR = 30.0
#: m: two neighbouring returns of one scan closer than this (or within 10 % of range of
#: each other) are one surface, drawn between them: a wall seen at a slant is not a sieve
TURN_JOIN = 0.3


def turned_views(
    ranges: np.ndarray,
    laser: LaserGeometry,
    poses: np.ndarray,
    source: np.ndarray,
    at: np.ndarray,
    turn: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The scans the laser would take at the robot poses `poses[at]` turned on the spot by
    `turn` rad, rendered from what the scans `source` saw (their returns drawn into one
    grid, `TURN_CELL`), and per rendered beam whether it left what they saw before meeting
    a return (it crossed a cell of `TURN_SEEN` no source beam passed through): such a beam
    is a no-return (NaN) in the view, as is one that meets nothing within `TURN_FAR` (or the
    laser's `range_max`). Why: a place taught
    by scans driven along it (a corridor's spans) was never seen from across, yet the robot
    turns on the spot there (docs/journal/places.md, session 28)."""
    r = np.asarray(ranges, dtype=np.float64)[source]
    lp = se2.laser_poses(np.asarray(poses, dtype=np.float64)[source], laser)
    bearing = lp[:, 2:3] + laser.angles[None, :]
    ok = np.isfinite(r) & (r > 0) & (r < laser.range_max)
    ex = lp[:, 0:1] + r * np.cos(bearing)
    ey = lp[:, 1:2] + r * np.sin(bearing)
    # the returns, and between neighbouring returns of one surface points a cell apart
    pair = ok[:, 1:] & ok[:, :-1]
    with np.errstate(invalid="ignore"):
        gap = np.hypot(ex[:, 1:] - ex[:, :-1], ey[:, 1:] - ey[:, :-1])
        one = pair & ((gap < TURN_JOIN) | (np.abs(np.diff(r, axis=1)) <= 0.1 * r[:, 1:]))
    steps = max(2, int(np.ceil(TURN_JOIN / TURN_CELL * 4)))
    f = np.linspace(0.0, 1.0, steps)[None, :]
    jx = ex[:, :-1][one][:, None] + f * (ex[:, 1:] - ex[:, :-1])[one][:, None]
    jy = ey[:, :-1][one][:, None] + f * (ey[:, 1:] - ey[:, :-1])[one][:, None]
    px = np.concatenate([ex[ok], jx.ravel()])
    py = np.concatenate([ey[ok], jy.ravel()])
    # the grid: around the source and the views' poses, out to `TURN_FAR`
    at_lp = se2.laser_poses(np.asarray(poses, dtype=np.float64)[at], laser)
    gone = np.isnan(r)  # a no-return saw free space out to `TURN_FAR`
    far_x = lp[:, 0:1] + TURN_FAR * np.cos(bearing)
    far_y = lp[:, 1:2] + TURN_FAR * np.sin(bearing)
    xs = np.concatenate([px, lp[:, 0], at_lp[:, 0], far_x[gone]])
    ys = np.concatenate([py, lp[:, 1], at_lp[:, 1], far_y[gone]])
    lo = np.array([xs.min(), ys.min()]) - 2 * TURN_CELL
    shape = (np.array([xs.max(), ys.max()]) + 2 * TURN_CELL - lo) / TURN_CELL
    nx, ny = (int(v) + 1 for v in shape)
    occupied = np.zeros((nx, ny), dtype=bool)
    occupied[_cell(px, lo[0], nx), _cell(py, lo[1], ny)] = True
    # what the source saw: the cells its beams crossed before their return (a no-return:
    # out to `TURN_FAR`)
    seen = np.zeros((nx // TURN_SEEN + 1, ny // TURN_SEEN + 1), dtype=bool)
    reach = np.where(ok, r - TURN_CELL, np.where(gone, TURN_FAR, 0.0))
    t = np.arange(0.0, min(TURN_FAR, float(reach.max(initial=0.0))) + TURN_CELL, TURN_CELL)
    for k in range(len(r)):  # a scan at a time: beams x samples
        inside = t[None, :] <= reach[k][:, None]
        sx = lp[k, 0] + t[None, :] * np.cos(bearing[k])[:, None]
        sy = lp[k, 1] + t[None, :] * np.sin(bearing[k])[:, None]
        ix, iy, within = _cells(sx[inside], sy[inside], lo, nx, ny)
        seen[ix[within] // TURN_SEEN, iy[within] // TURN_SEEN] = True
    # the views: each beam marched half a cell at a time to its first occupied cell
    robot = np.asarray(poses, dtype=np.float64)[at].copy()
    robot[:, 2] += turn
    view_lp = se2.laser_poses(robot, laser)
    t = np.arange(0.0, min(TURN_FAR, laser.range_max), TURN_CELL / 4)
    out = np.full((len(at), laser.beams), np.nan, dtype=np.float32)
    unseen = np.zeros((len(at), laser.beams), dtype=bool)
    for k in range(len(at)):
        b = view_lp[k, 2] + laser.angles
        sx = view_lp[k, 0] + t[None, :] * np.cos(b)[:, None]
        sy = view_lp[k, 1] + t[None, :] * np.sin(b)[:, None]
        ix, iy, within = _cells(sx, sy, lo, nx, ny)
        hit = within & occupied[ix, iy]
        left = ~within | ~seen[ix // TURN_SEEN, iy // TURN_SEEN]
        first = np.where(hit.any(axis=1), hit.argmax(axis=1), len(t))
        away = np.where(left.any(axis=1), left.argmax(axis=1), len(t))
        found = (first < len(t)) & (first <= away)
        out[k, found] = t[first[found]]
        unseen[k] = ~found & (away < len(t))
    out[out < max(laser.range_min, 1e-3)] = np.nan
    return out, unseen


def _cell(v: np.ndarray, lo: float, n: int) -> np.ndarray:
    return np.clip(((v - lo) / TURN_CELL).astype(np.int64), 0, n - 1)


def _cells(
    x: np.ndarray, y: np.ndarray, lo: np.ndarray, nx: int, ny: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid cells of points, clipped into the grid, and whether each point lies inside it."""
    fx, fy = (x - lo[0]) / TURN_CELL, (y - lo[1]) / TURN_CELL
    within = (fx >= 0) & (fx < nx) & (fy >= 0) & (fy < ny)
    ix = np.clip(fx.astype(np.int64), 0, nx - 1)
    iy = np.clip(fy.astype(np.int64), 0, ny - 1)
    return ix, iy, within
