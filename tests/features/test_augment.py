"""The taught scans' copies with the less open side opened or closed (augment.py), on the
ray-cast test world: a 2 m corridor, a room opening on its left (x 12-16) and an 8 m hall
open on both sides (x 26-34)."""

from __future__ import annotations

import numpy as np

from tests.features.world import LASER, cast, drive
from toolkit.features.augment import (
    PANE_HALF,
    across_left,
    changed,
    closed,
    closed_left,
    ended,
    glass_across,
    glazable,
    glazed,
    mirror_index,
    opened,
    started,
    stretched,
    to_width,
    turned_views,
    usual_wall,
    usual_width,
    walled_across,
    width_factor,
)
from toolkit.features.descriptors import (
    ABSOLUTE,
    WIDTH_LIKE,
    describe,
    metres_columns,
    names,
    place_columns,
    rescaled,
    with_metres,
)


def _scans() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    _, poses, label = drive()
    return cast(poses), poses, label


def test_mirror_index_pairs_opposite_bearings() -> None:
    j = mirror_index(LASER)
    assert np.allclose(LASER.angles[j], -LASER.angles, atol=1e-9)


def test_opened_copies_the_room_onto_the_wall_side() -> None:
    r, poses, _ = _scans()
    at = np.argmin(np.abs(poses[:, 0] - 14.0))  # beside the room's opening (left, +y)
    left, right = LASER.angles > np.radians(60), LASER.angles < -np.radians(60)
    assert np.nanmedian(r[at, right]) < 1.5  # the corridor's right wall
    o = opened(r, LASER)[at]
    assert np.nanmedian(o[right]) > 2.5  # the room on both sides now
    assert np.allclose(o[left], r[at, left], equal_nan=True)  # the open side as it was
    assert changed(r[[at]], o[None], LASER)[0]


def test_closed_walls_the_less_open_side_at_the_usual_distance() -> None:
    r, poses, label = _scans()
    wall = usual_wall(r, LASER)
    assert 0.8 < wall < 1.2  # the 2 m corridor's walls, 1 m either side of the path
    c = closed(r, LASER)
    hall = np.flatnonzero(label == "hall")
    left, right = LASER.angles > np.radians(60), LASER.angles < -np.radians(60)
    lateral = np.abs(c[hall] * np.sin(LASER.angles))
    near = np.minimum(
        np.nanmedian(lateral[:, left], axis=1), np.nanmedian(lateral[:, right], axis=1)
    )
    far = np.maximum(
        np.nanmedian(lateral[:, left], axis=1), np.nanmedian(lateral[:, right], axis=1)
    )
    assert np.all(near < 1.3) and np.median(far) > 3.0  # one side walled, the other open
    # a corridor scan is its own closed copy: its walls are nearer than the usual wall
    corridor = np.flatnonzero((label == "corridor") & (poses[:, 0] < 11))
    assert changed(r[corridor], c[corridor], LASER).mean() < 0.1
    assert changed(r[hall], c[hall], LASER).mean() > 0.5  # (the hall walled: a new kind)


def test_a_room_across_from_glass_is_walled_across_not_itself() -> None:
    # beside the room (left, x 12-16) with a window across the path: the right wall's beams
    # at 30-150 degrees give no return (glass), which `closed` takes for the more open side
    r, poses, _ = _scans()
    at = np.flatnonzero((poses[:, 0] > 13.0) & (poses[:, 0] < 14.0))  # short of the lobby
    right = (LASER.angles < 0) & (np.abs(np.sin(LASER.angles)) >= 0.5)
    glass = r[at].copy()
    glass[:, right] = np.nan
    assert closed_left(glass, LASER).all()  # closed walls the room (the left)
    assert not across_left(glass, LASER).any()  # the room is seen through: the right across
    # without the glass both wall the right
    assert not closed_left(r[at], LASER).any() and not across_left(r[at], LASER).any()
    assert glass_across(glass, LASER).all() and not glass_across(r[at], LASER).any()
    w = walled_across(glass, LASER, wall=1.0)
    left = LASER.angles > np.radians(60)
    assert np.allclose(w[:, left], r[at][:, left], equal_nan=True)  # the room kept
    # the glass walled at 1 m: the scan without the window (the corridor's right wall at 1 m,
    # short of the lobby that the beams at 30-60 degrees reach)
    wall = LASER.angles < -np.radians(60)
    assert np.nanmax(np.abs(w[:, wall] - r[at][:, wall])) < 0.15  # the sway: up to 0.1 m
    assert not changed(r[at], w, LASER).any()
    # and the window put back across the room's scan (glazed): no return on the right within
    # PANE_HALF m along the path but near normal, the room as it was
    g = glazed(r[at], LASER)
    assert glazable(r[at], LASER).all()  # the room seen through, nothing through the wall
    pane = right & (np.abs(np.cos(LASER.angles)) <= PANE_HALF * np.abs(np.sin(LASER.angles)))
    oblique = pane & (np.abs(np.cos(LASER.angles)) > np.sin(np.radians(15.0)))
    assert np.isnan(g[:, oblique]).all() and np.isfinite(r[at][:, oblique]).all()
    assert np.allclose(g[:, left], r[at][:, left], equal_nan=True)
    assert changed(r[at], g, LASER).all()


def test_ended_copy_of_the_hall_is_the_scan_at_its_end() -> None:
    # the 8 m hall (x 26-34) ends in the 2 m corridor: a scan at its middle closed 0.5 m
    # ahead sees, ahead of it, what the scan 0.5 m before the hall's end sees
    r = cast(np.array([[30.0, 0.0, 0.0], [33.5, 0.0, 0.0], [8.0, 0.0, 0.0]]), sigma=0.0)
    copy = ended(r, LASER, ahead=True, wall=1.0)
    deg = np.degrees(np.abs(LASER.angles))
    front = (deg > 20) & (deg < 85)  # beside and ahead, short of the corridor's far end
    assert np.nanmax(np.abs(r[0, front] - r[1, front])) > 2.0  # the middle is not the end
    assert np.nanmax(np.abs(copy[0, front] - r[1, front])) < 0.02
    behind = np.cos(LASER.angles) < 0
    assert np.array_equal(copy[0, behind], r[0, behind], equal_nan=True)  # behind: kept
    # a corridor scan is its own copy; the hall's middle is not
    assert not changed(r[[2]], copy[[2]], LASER)[0] and changed(r[[0]], copy[[0]], LASER)[0]
    back = ended(r, LASER, ahead=False, wall=1.0)  # behind: the mirror image
    assert np.array_equal(back[0, ~behind], r[0, ~behind], equal_nan=True)


def test_started_copy_of_the_hall_is_the_scan_just_before_it() -> None:
    # the 8 m hall (x 26-34, 4 m either side) is entered from the lobby (2.5 m either
    # side): a scan at the hall's middle with the lobby's walls up to 0.5 m ahead sees, beside
    # and ahead of it, what the scan 0.5 m before the hall sees
    r = cast(np.array([[30.0, 0.0, 0.0], [25.5, 0.0, 0.0], [8.0, 0.0, 0.0]]), sigma=0.0)
    copy = started(r, LASER, ahead=True, wall=2.5)
    deg = np.degrees(np.abs(LASER.angles))
    side = (deg >= 50) & (deg <= 90)  # short of the hall's far end from the middle
    assert np.nanmax(np.abs(r[0, side] - r[1, side])) > 1.0  # the middle is not the start
    assert np.nanmax(np.abs(copy[0, side] - r[1, side])) < 1e-3
    # at the corridor's walls (1 m) the hall's middle is a new kind, a corridor scan itself
    narrow = started(r, LASER, ahead=True, wall=1.0)
    assert changed(r[[0]], narrow[[0]], LASER)[0] and not changed(r[[2]], narrow[[2]], LASER)[0]
    # behind (the hall ended 0.5 m behind): every beam ahead walled at 2.5 m across the path
    back = started(r, LASER, ahead=False, wall=2.5)
    walled = np.fmin(r[0], 2.5 / np.maximum(np.abs(np.sin(LASER.angles)), 1e-6))
    assert np.allclose(back[0, deg > 20], walled[deg > 20], atol=1e-4, equal_nan=True)


def test_stretched_doubles_the_width_and_keeps_the_length_along_the_path() -> None:
    r, _, label = _scans()
    corridor = np.flatnonzero(label == "corridor")
    assert 1.9 < usual_width(r[corridor], LASER) < 2.1  # the 2 m corridor
    s = stretched(r, LASER, 2.0)
    assert 3.8 < usual_width(s[corridor], LASER) < 4.2
    # an end point (x, y) lands at (x, 2 y): beside the laser the walls are twice as far
    side = np.abs(np.sin(LASER.angles)) > 0.99
    assert np.allclose(
        np.nanmedian(s[corridor][:, side]), 2 * np.nanmedian(r[corridor][:, side]), rtol=0.05
    )
    ahead = np.argmin(np.abs(LASER.angles))  # the beam straight ahead: x kept
    assert np.allclose(s[:, ahead], r[:, ahead], equal_nan=True)
    w = to_width(r[corridor], LASER, 3.0)
    assert 2.85 < usual_width(w, LASER) < 3.15


def test_rescaled_widths_are_the_stretched_scans_without_resampling() -> None:
    r, _, label = _scans()
    corridor = np.flatnonzero(label == "corridor")
    columns = place_columns()
    width = np.isin(np.asarray(names())[columns], WIDTH_LIKE)
    x = describe(r[corridor], LASER)[:, columns]
    s = describe(stretched(r[corridor], LASER, 2.0), LASER)[:, columns]
    y = rescaled(x.copy(), columns, 2.0)
    # the widths beside the laser are the stretched scan's: log 2 more (medians over scans)
    assert np.allclose(np.median(y[:, width], axis=0), np.median(s[:, width], axis=0), atol=0.05)
    assert np.allclose(np.median(y[:, width] - x[:, width], axis=0), np.log(2.0))
    # every other descriptor is the scan's own, where the resampled scan's are not
    assert np.array_equal(y[:, ~width], x[:, ~width])
    assert np.abs(s[:, ~width] - x[:, ~width]).max() > 0.1
    assert np.array_equal(rescaled(x.copy(), columns, 1.0), x)  # factor 1: the scan's
    assert 0.95 < width_factor(r[corridor], LASER, 2.0) < 1.05  # the 2 m corridor


def test_reach_in_metres_follows_the_rescaled_descriptors_as_measured() -> None:
    """`Config.reach_metres`: the reach beside the laser once more, not rescaled (a door's
    room keeps its depth in metres whatever the corridor's width)."""
    r, _, _ = _scans()
    columns = place_columns()
    x = describe(r, LASER)[:, columns]
    k, m = len(columns), metres_columns(columns)
    assert [names()[c] for c in columns[m]] == list(ABSOLUTE)
    y = with_metres(x.copy(), columns, 2.0, True)
    assert y.shape == (len(r), k + len(ABSOLUTE))
    assert np.array_equal(y[:, :k], rescaled(x.copy(), columns, 2.0))  # as without
    assert np.array_equal(y[:, k:], x[:, m])  # as measured
    seen = np.isfinite(y[:, k:]).all(axis=1)
    assert seen.mean() > 0.9
    assert np.allclose(y[seen][:, m] - y[seen][:, k:], np.log(2.0))  # the rescaled: log 2 more
    assert np.array_equal(with_metres(x.copy(), columns, 2.0, False), y[:, :k])  # off: as before


def test_turned_views_render_the_corridor_seen_across() -> None:
    """Scans driven along the corridor (x 1-11, heading +x), rendered from x 6 turned by 90
    degrees: the beams that meet a wall the scans saw give its range (the simulated laser's
    own at that pose, within noise and a cell); those that look back along the corridor
    past where the scans saw leave what they saw and are no-returns."""
    poses = np.column_stack([np.arange(1.0, 11.5, 1.0), np.zeros(11), np.zeros(11)])
    r = cast(poses)
    at = np.array([5])  # x 6
    view, unseen = turned_views(r, LASER, poses, np.arange(11), at, np.pi / 2)
    turned = poses[at].copy()
    turned[:, 2] += np.pi / 2
    truth = cast(turned, sigma=0.0)[0]
    both = np.isfinite(view[0]) & np.isfinite(truth)
    assert both.mean() > 0.8  # the left wall and the corridor ahead (+x) were seen
    assert np.percentile(np.abs(view[0] - truth)[both], 90) < 0.08
    back = LASER.angles > np.radians(80)  # looking along -x, past the first scan's x 1
    assert unseen[0, back].all() and np.isnan(view[0, back]).all()
    assert not unseen[0, np.abs(LASER.angles) < np.radians(10)].any()  # the wall ahead
    ahead, _ = turned_views(r, LASER, poses, np.arange(11), at, 0.0)  # not turned: the scan
    assert (np.isnan(ahead[0]) == np.isnan(r[5])).mean() > 0.95  # past range_max alike
    near = np.isfinite(ahead[0]) & np.isfinite(r[5])
    assert np.median(np.abs(ahead[0] - r[5])[near]) < 0.05


def test_turned_copies_of_the_spans_driven_straight() -> None:
    """`fitting.turned_copies`: a view per taught scan and heading of `turned_by`; with
    `turned_spans` "straight" only the span driven along the corridor, not the one turning
    on the spot in the room (it has its own views); "all" (the default) both; `turned_of`
    names places."""
    from toolkit.features.fitting import turned_copies
    from toolkit.features.model import Config

    drive_ = np.column_stack([np.arange(1.0, 11.5, 1.0), np.zeros(11), np.zeros(11)])
    spin = np.column_stack([np.full(6, 14.0), np.full(6, 2.5), np.linspace(0, 2.5, 6)])
    poses = np.vstack([drive_, spin])
    r = cast(poses)
    spans = [("corridor", np.arange(2, 9)), ("room", np.arange(11, 17))]
    on = Config(augment_turned=1.0, turned_by=(90.0, -90.0, 180.0), turned_spans="straight")
    out = turned_copies(r, LASER, poses, spans, on)
    assert [round(float(np.degrees(t))) for t, _, _ in out] == [90, -90, 180]
    assert all(
        np.array_equal(rows, np.arange(2, 9)) and v.shape == (7, LASER.beams) for _, rows, v in out
    )
    both = turned_copies(r, LASER, poses, spans, Config(augment_turned=1.0, turned_by=(90.0,)))
    assert [len(rows) for _, rows, _ in both] == [13]  # the default: every span
    rooms = Config(augment_turned=1.0, turned_of=("room",))
    assert [len(rows) for _, rows, _ in turned_copies(r, LASER, poses, spans, rooms)] == [6] * 4
