"""Random worlds: buildings the place model has never seen (`toolkit simulate random --seed N`).

A world is a chain of corridors (3 to 5 legs, alternately along +x and +-y, so that it never
crosses itself) of one random width in 1.6-4 m and random leg lengths, with:

- open doors into rooms (3-5 m wide, 3-4 m deep) and closed doors (a shallow niche);
- windows of 1.5-10 m, glass panes between mullions (glass: no return but near normal);
- one hall, 8-14 m long and 4-8 m deep on one or both sides, with columns and tables;
- clutter along the walls (boxes, bins) that narrows the corridor here and there.

The place kinds, each a label of the robot's laser position (where the robot IS, not what
it sees ahead), the same on every world: "door" (beside an open door, 0.4 m either side of
it), "window" (beside a window), "hall" (in the hall's stretch of corridor), "corner" (in the
crossing of two legs, 0.3 m either side) and "corridor" (everywhere else, closed doors and
clutter included). Labels do not depend on the direction of travel, so a second run the
other way round is scored by the same zones.

The world is drawn from `seed`; `route` picks the path through it: 0 from the first leg to
the last, 1 the other way round, each at its own speed and lateral offset (up to a fifth of
the width off the centre line). The noise of the laser and odometry is the simulator's, from
its own seed.

With `entered` (off by default: every world and path as without it, to the bit) the path also
enters rooms, as the Intel lab's robot does: before at least two of the open doors (each
with probability 0.6, the same doors on both routes) the robot turns on the spot to face the
door, drives to the room's middle, turns to look left and right along it, and comes back out
and turns to go on. The laser inside a room is labelled "room" (a zone per room, entered or
not); the turns in front of a door are in the door's zone. The world itself is unchanged.

With `brief` as well (off by default; session 26, issue 16), the rooms are entered as the
Intel lab's are: the building has four open doors or more where they fit; two large rooms
(4.5-6.5 m wide, 4.5-6 m deep; drawn from their own generator) are entered as above, and
every other open door leads to a small room (2.2-3.2 m wide, 2.2-3 m deep) that the robot
enters briefly: it turns to the door, drives 1-1.8 m in, turns a quarter to look one way
along the room, and turns back out through the door (about 8-10 scans at 1 m or 0.5 rad,
3-4 rad turned: the Intel rooms' short visits, which are lost to the corridor).

With `revisit` (off by default: every world and path as without it, to the bit; session 28,
issue 16) the path comes back: having reached the last leg's end it turns on the spot (a
quarter turn, a step sideways to its own lateral offset, another quarter turn) and drives
back along the chain to where it started, turning on the spot at the corners as on the way
out. The way back's offset and the rooms it enters are drawn from their own generator, so
every other draw is unchanged. With `entered` it enters each room with probability
`ENTER_SHARE`, whether or not it was entered on the way out (with `brief`: a small room
briefly, a large one fully), as the Intel lab's robot enters some rooms on one pass round
its ring and not on another. So every stretch of corridor is seen twice, once each way; the
regions (ten scans per place) are still drawn from each place's first occurrence, on the
way out.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from toolkit.sim.geometry import WorldBuilder
from toolkit.sim.scenarios import Scenario, Zone

PLACES = ("corridor", "door", "window", "hall", "corner")
SCAN_RATE = 5.0  # Hz
DOOR_WIDTH = 0.9  # m
DOOR_MARGIN = 0.4  # m either side of an open door: the zone "door"
CORNER_MARGIN = 0.3  # m either side of the crossing: the zone "corner"
ENTER_SHARE = 0.6  # with `entered`: the share of the open doors whose room the path enters
BRIEF_DOORS = 4  # with `brief`: open doors drawn until at least this many (where they fit)
BRIEF_WIDER = 1.5  # with `brief`: m added to every room's width (the rooms entered fully)


@dataclass
class _Leg:
    start: np.ndarray  # centre line, (2,)
    end: np.ndarray
    left: tuple[np.ndarray, np.ndarray]  # wall ends
    right: tuple[np.ndarray, np.ndarray]

    @property
    def direction(self) -> np.ndarray:
        d = self.end - self.start
        return np.asarray(d / np.hypot(*d))

    @property
    def length(self) -> float:
        return float(np.hypot(*(self.end - self.start)))

    @property
    def horizontal(self) -> bool:
        return bool(abs(self.direction[0]) > 0.5)


def _normal(d: np.ndarray) -> np.ndarray:
    """The left normal of a direction."""
    return np.array([-d[1], d[0]])


def _offset(vertices: np.ndarray, h: float) -> np.ndarray:
    """The polyline of axis-aligned legs offset by `h` to the left (corners meet squarely)."""
    d = np.diff(vertices, axis=0)
    n = np.array([_normal(v / np.hypot(*v)) for v in d])
    shift = np.zeros_like(vertices)
    shift[:-1] += n
    shift[1:] += n  # interior vertices: n_prev + n_next (the offset lines meet at 90°)
    return vertices + h * shift


def _centre_line(rng: np.random.Generator) -> np.ndarray:
    """3-5 legs: +x, then alternately +-y and +x."""
    legs = int(rng.integers(3, 6))
    points = [np.zeros(2)]
    for k in range(legs):
        if k % 2 == 0:
            step = np.array([rng.uniform(22.0, 40.0), 0.0])
        else:
            step = np.array([0.0, rng.choice([-1.0, 1.0]) * rng.uniform(12.0, 24.0)])
        points.append(points[-1] + step)
    return np.array(points)


class _Sides:
    """Occupied stretches of a leg (in metres along its centre line), per side."""

    def __init__(self, length: float, margin: float) -> None:
        self.length, self.margin = length, margin
        self.taken: dict[int, list[tuple[float, float]]] = {1: [], -1: []}

    def place(
        self, rng: np.random.Generator, size: float, side: int, lo: float, gap: float = 1.5
    ) -> float | None:
        """A free start u for an item of `size` on `side` (both sides: 0), or None."""
        for _ in range(30):
            hi = self.length - lo - size
            if hi <= lo:
                return None
            u = float(rng.uniform(lo, hi))
            sides = (1, -1) if side == 0 else (side,)
            if all(u + size + gap <= a or u >= b + gap for s in sides for a, b in self.taken[s]):
                for s in sides:
                    self.taken[s].append((u, u + size))
                return u
        return None


def random_world(
    seed: int = 0,
    route: int = 0,
    entered: bool = False,
    brief: bool = False,
    revisit: bool = False,
) -> Scenario:
    """A random building (see the module docstring), and a path through it by `route`; with
    `entered`, one that also enters rooms through their doors (labelled "room"); with `brief`
    too, small rooms entered briefly beside two entered fully; with `revisit`, a path that
    comes back along the chain to its start."""
    if brief and not entered:
        raise ValueError("brief room visits need entered")
    rng = np.random.default_rng([seed, 16])
    width = float(rng.uniform(1.6, 4.0))
    h = width / 2
    centre = _centre_line(rng)
    lefts, rights = _offset(centre, h), _offset(centre, -h)
    legs = [
        _Leg(centre[k], centre[k + 1], (lefts[k], lefts[k + 1]), (rights[k], rights[k + 1]))
        for k in range(len(centre) - 1)
    ]
    b = WorldBuilder()
    zones: list[Zone] = []
    openings: dict[tuple[int, int], list[tuple[float, float, str]]] = {}
    placed: list[tuple[int, int, float, float, float]] = []  # leg, side, door start, w, depth

    def along(leg: _Leg, u0: float, u1: float, margin: float, label: str) -> Zone:
        a = leg.start + leg.direction * (u0 - margin)
        c = leg.start + leg.direction * (u1 + margin)
        n = _normal(leg.direction) * h
        xs = [a[0] + n[0], a[0] - n[0], c[0] + n[0], c[0] - n[0]]
        ys = [a[1] + n[1], a[1] - n[1], c[1] + n[1], c[1] - n[1]]
        return Zone(label, min(xs), min(ys), max(xs), max(ys))

    sides = [_Sides(leg.length, 0.0) for leg in legs]
    horizontal = [k for k, leg in enumerate(legs) if leg.horizontal]
    room_margin = width + 4.0  # rooms and the hall keep clear of the next leg

    # the hall: on a horizontal leg, one side or both
    roomy = [k for k in horizontal if legs[k].length >= 30.0] or [
        max(horizontal, key=lambda k: legs[k].length)
    ]
    k_hall = int(rng.choice(roomy))
    hall_len = min(float(rng.uniform(8.0, 14.0)), legs[k_hall].length - 2 * room_margin - 0.5)
    hall_depth = float(rng.uniform(4.0, 8.0))
    hall_side = int(rng.choice([1, -1, 0]))
    u_hall = sides[k_hall].place(rng, hall_len, 0, room_margin, gap=2.5)
    if u_hall is None:  # the leg is long enough by construction; never here
        raise RuntimeError("no room for the hall")
    leg = legs[k_hall]
    for s in (1, -1) if hall_side == 0 else (hall_side,):
        openings.setdefault((k_hall, s), []).append((u_hall, u_hall + hall_len, "gap"))
        _hall(b, rng, leg, s, h, u_hall, hall_len, hall_depth)
    zones.append(along(leg, u_hall, u_hall + hall_len, 0.0, "hall"))

    # open doors: 2-5, on horizontal legs, rooms behind them
    doors = 0
    for _ in range(int(rng.integers(3, 6)) * 4):
        if doors >= (BRIEF_DOORS if brief else 2) and rng.random() < 0.3:
            break
        k = int(rng.choice(horizontal))
        s = int(rng.choice([1, -1]))
        room_w = float(rng.uniform(3.0, 5.0)) + (BRIEF_WIDER if brief else 0.0)
        u = sides[k].place(rng, room_w, s, room_margin)
        if u is None:
            continue
        d0 = u + room_w / 2 - DOOR_WIDTH / 2
        openings.setdefault((k, s), []).append((d0, d0 + DOOR_WIDTH, "door"))
        placed.append((k, s, d0, room_w, float(rng.uniform(3.0, 4.0))))
        zones.append(along(legs[k], d0, d0 + DOOR_WIDTH, DOOR_MARGIN, "door"))
        doors += 1
        if doors >= 5:
            break

    visits = _brief_rooms(placed, seed) if brief else None  # the small rooms, in place
    rooms: dict[tuple[int, int], list[tuple[float, float]]] = {}  # per wall: (width, depth)
    for k, s, _, w, depth in placed:
        rooms.setdefault((k, s), []).append((w, depth))

    # windows: 1-3, any leg
    wanted, windows = int(rng.integers(1, 4)), 0
    for _ in range(40):
        if windows >= wanted:
            break
        k = int(rng.integers(len(legs)))
        s = int(rng.choice([1, -1]))
        length = float(rng.uniform(1.5, 10.0))
        u = sides[k].place(rng, length, s, width + 1.0)
        if u is None:
            continue
        windows += 1
        panes = max(1, round(length / float(rng.uniform(1.2, 2.0))))
        edges = np.linspace(u, u + length, panes + 1)
        for p0, p1 in itertools.pairwise(edges):
            openings.setdefault((k, s), []).append((p0 + 0.05, p1 - 0.05, "glass"))
        zones.append(along(legs[k], u, u + length, 0.0, "window"))

    # closed doors (niches) and clutter: not places, the corridor's variety
    niches: list[tuple[int, int, float]] = []
    for _ in range(int(rng.integers(1, 4))):
        k = int(rng.integers(len(legs)))
        s = int(rng.choice([1, -1]))
        u = sides[k].place(rng, DOOR_WIDTH, s, width + 1.0, gap=1.0)
        if u is not None:
            openings.setdefault((k, s), []).append((u, u + DOOR_WIDTH, "gap"))
            niches.append((k, s, u))
    clutter: list[tuple[int, int, float, float, float]] = []
    for _ in range(int(rng.integers(2, 7))):
        k = int(rng.integers(len(legs)))
        s = int(rng.choice([1, -1]))
        size = float(rng.uniform(0.3, 0.9))
        u = sides[k].place(rng, size, s, width + 1.0, gap=1.0)
        if u is not None:
            clutter.append((k, s, u, size, float(rng.uniform(0.2, min(0.6, 0.25 * width)))))

    # the walls, with their openings (positions along the wall, from its first end)
    for k, leg in enumerate(legs):
        for s, (p0, p1) in ((1, leg.left), (-1, leg.right)):
            shift = float(np.dot(p0 - leg.start, leg.direction))
            outward = _pt(_normal(leg.direction) * s)
            ops = [(a - shift, c - shift, kind) for a, c, kind in openings.get((k, s), [])]
            doors_here = [o for o in ops if o[2] == "door"]
            sizes = rooms.get((k, s), [])
            # WorldBuilder.wall takes one room size per wall: build door by door
            plain = [o for o in ops if o[2] != "door"]
            b.wall(_pt(p0), _pt(p1), plain + [(a, c, "gap") for a, c, _ in doors_here])
            for (a, c, _), room in zip(
                sorted(doors_here), _ordered(doors_here, sizes), strict=True
            ):
                _room(b, p0, leg.direction, outward, a, c, room)
    for k, s, u in niches:
        leg = legs[k]
        n = _normal(leg.direction) * s
        q0 = leg.start + leg.direction * u + n * h
        q1 = q0 + leg.direction * DOOR_WIDTH
        b.polyline([_pt(q0), _pt(q0 + n * 0.12), _pt(q1 + n * 0.12), _pt(q1)])
    for k, s, u, size, depth in clutter:
        leg = legs[k]
        n = _normal(leg.direction) * s
        q0 = leg.start + leg.direction * u + n * h
        if rng.random() < 0.3:
            q1 = q0 + leg.direction * size / 2 - n * 0.2
            b.circle(float(q1[0]), float(q1[1]), 0.18)
        else:
            q1 = q0 + leg.direction * size - n * depth
            b.box(min(q0[0], q1[0]), min(q0[1], q1[1]), max(q0[0], q1[0]), max(q0[1], q1[1]))
    # end walls
    b.segment(_pt(legs[0].left[0]), _pt(legs[0].right[0]))
    b.segment(_pt(legs[-1].left[1]), _pt(legs[-1].right[1]))

    # corners first: the first matching zone wins
    for v in centre[1:-1]:
        m = h + CORNER_MARGIN
        zones.insert(0, Zone("corner", v[0] - m, v[1] - m, v[0] + m, v[1] + m))

    path_rng = np.random.default_rng([seed, 16, route])
    offset = float(path_rng.uniform(-0.2, 0.2)) * width
    way = _offset(centre, offset)
    way[0] += legs[0].direction * 1.0
    way[-1] -= legs[-1].direction * 1.0
    if entered:
        way = _entering(way, legs, placed, offset, h, seed, visits)
        zones += [_room_zone(legs[k], s, d0, w, depth, h) for k, s, d0, w, depth in placed]
    if route % 2 == 1:
        way = way[::-1]
    if revisit:
        way = np.concatenate(
            [way, _way_back(centre, legs, placed, width, seed, route, entered, visits)]
        )
    speed = float(path_rng.uniform(0.35, 0.6))
    turn_rate = 0.5
    length = float(np.hypot(*np.diff(way, axis=0).T).sum())
    if entered or revisit:  # turns of any angle (in a room, half turns)
        d = np.diff(way, axis=0)
        turned = float(np.abs(np.diff(np.unwrap(np.arctan2(d[:, 1], d[:, 0])))).sum())
        seconds = length / speed + turned / turn_rate
    else:
        seconds = length / speed + (len(way) - 2) * (np.pi / 2) / turn_rate
    return Scenario(
        name="random",
        world=b.build(),
        waypoints=way,
        zones=zones,
        default_label="corridor",
        scans=round(seconds * SCAN_RATE),
        speed=speed,
        turn_rate=turn_rate,
        laser={"mount_x": 0.12, "mount_z": 0.35},
        # a user's regions: ten scans of each place's first occurrence, in one or two spans
        region_parts={
            p: int(parts) for p, parts in zip(PLACES, rng.integers(1, 3, len(PLACES)), strict=True)
        },
    )


def _brief_rooms(
    placed: list[tuple[int, int, float, float, float]], seed: int
) -> dict[int, tuple[float, int]]:
    """With `brief`: two rooms of `placed` (drawn from their own generator) made deep (4.5-6
    m; their width is already 4.5-6.5 m) and every other made small around its door, in
    place (the Intel lab's taught rooms are large, its rooms lost on short visits small);
    per small room its visit: how far in (m) and which way it looks (+-1 along the leg)."""
    rng = np.random.default_rng([seed, 16, 26])
    full = rng.permutation(len(placed))[:2]
    visits = {}
    for i, (k, s, d0, wide, _) in enumerate(placed):
        w, depth = float(rng.uniform(2.2, 3.2)), float(rng.uniform(2.2, 3.0))
        step_in, way = float(rng.uniform(1.0, 1.8)), int(rng.choice([1, -1]))
        deep = float(rng.uniform(4.5, 6.0))
        if i in full:
            placed[i] = (k, s, d0, wide, deep)
        else:
            placed[i] = (k, s, d0, w, depth)
            visits[i] = (min(step_in, depth - 0.6), way)
    return visits


def _way_back(
    centre: np.ndarray,
    legs: list[_Leg],
    placed: list[tuple[int, int, float, float, float]],
    width: float,
    seed: int,
    route: int,
    entered: bool,
    visits: dict[int, tuple[float, int]] | None,
) -> np.ndarray:
    """With `revisit`: the waypoints from the far end of `route`'s path back to its start, on
    a lateral offset of its own (up to a fifth of the width off the centre line), with
    `entered` into each room with probability `ENTER_SHARE` (entered on the way out or not);
    drawn from their own generator, so that every other draw is unchanged."""
    rng = np.random.default_rng([seed, 16, route, 28])
    offset = float(rng.uniform(-0.2, 0.2)) * width
    way = _offset(centre, offset)
    way[0] += legs[0].direction * 1.0
    way[-1] -= legs[-1].direction * 1.0
    if entered:
        pick = rng.random(len(placed)) < ENTER_SHARE
        way = _entering(way, legs, placed, offset, width / 2, seed, visits, pick)
    return way if route % 2 == 1 else way[::-1]


def _entering(
    way: np.ndarray,
    legs: list[_Leg],
    placed: list[tuple[int, int, float, float, float]],
    offset: float,
    h: float,
    seed: int,
    visits: dict[int, tuple[float, int]] | None = None,
    pick: np.ndarray | None = None,
) -> np.ndarray:
    """The waypoints `way` (route 0) with detours into rooms: at least two of the `placed`
    rooms (leg, side, door start, width, depth), each with probability `ENTER_SHARE`, drawn
    from their own generator so that the world's draws are unchanged; with `visits` (`brief`),
    every room, those not in it entered fully and those in it briefly (in, a look one way,
    out); with `pick` (the way back of `revisit`), the rooms it marks."""
    if pick is None and visits is None:
        rng = np.random.default_rng([seed, 16, 25])
        pick = rng.random(len(placed)) < ENTER_SHARE
        if pick.sum() < 2:
            pick[rng.permutation(len(placed))[:2]] = True
    elif pick is None:
        pick = np.ones(len(placed), dtype=bool)
    out: list[np.ndarray] = [way[0]]
    for k, leg in enumerate(legs):
        here = sorted(
            (int(i) for i in np.flatnonzero(pick) if placed[i][0] == k), key=lambda i: placed[i][2]
        )
        for i in here:
            _, s, d0, w, depth = placed[i]
            u = d0 + DOOR_WIDTH / 2
            n = _normal(leg.direction) * s
            front = leg.start + leg.direction * u + _normal(leg.direction) * offset
            if visits is not None and i in visits:  # a step or two in, a look one way, out
                step_in, side = visits[i]
                inside = leg.start + leg.direction * u + n * (h + step_in)
                out += [front, inside, inside + leg.direction * (0.3 * side), front]
                continue
            middle = leg.start + leg.direction * u + n * (h + depth / 2)
            look = leg.direction * (w / 4)
            out += [front, middle, middle + look, middle - look, middle, front]
        out.append(way[k + 1])
    return np.array(out)


def _room_zone(leg: _Leg, side: int, d0: float, w: float, depth: float, h: float) -> Zone:
    """The room behind the door at `d0` on `side` of `leg`: "room"."""
    n = _normal(leg.direction) * side
    c = leg.start + leg.direction * (d0 + DOOR_WIDTH / 2)
    pts = [c + leg.direction * a + n * b for a in (-w / 2, w / 2) for b in (h, h + depth)]
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    return Zone("room", min(xs), min(ys), max(xs), max(ys))


def _pt(p: np.ndarray) -> tuple[float, float]:
    return float(p[0]), float(p[1])


def _ordered(
    doors: list[tuple[float, float, str]], sizes: list[tuple[float, float]]
) -> list[tuple[float, float]]:
    """Room sizes in the order of the doors along the wall (they were drawn in placing order)."""
    order = np.argsort([a for a, _, _ in doors])
    return [sizes[i] for i in order]


def _room(
    b: WorldBuilder,
    p0: np.ndarray,
    direction: np.ndarray,
    outward: tuple[float, float],
    d0: float,
    d1: float,
    room: tuple[float, float],
) -> None:
    """A room (width along the wall, depth outward) centred on the door from d0 to d1."""
    width, depth = room
    n = np.asarray(outward)
    c = 0.5 * (d0 + d1)
    near = [p0 + direction * (c - width / 2), p0 + direction * (c + width / 2)]
    pts = [near[0], near[0] + n * depth, near[1] + n * depth, near[1]]
    b.polyline([_pt(q) for q in pts])  # the wall itself runs on either side of the door


def _hall(
    b: WorldBuilder,
    rng: np.random.Generator,
    leg: _Leg,
    side: int,
    h: float,
    u: float,
    length: float,
    depth: float,
) -> None:
    """The hall's walls beyond the corridor's side `side`, its columns and tables."""
    n = _normal(leg.direction) * side
    a = leg.start + leg.direction * u + n * h
    c = a + leg.direction * length
    b.polyline([_pt(a), _pt(a + n * depth), _pt(c + n * depth), _pt(c)])
    rows = 1 if depth < 6.0 else 2
    cols = max(2, int(length // 4.0))
    r = float(rng.uniform(0.15, 0.35))
    for i in range(cols):
        for j in range(rows):
            q = a + leg.direction * (length * (i + 0.5) / cols) + n * (depth * (j + 1) / (rows + 1))
            if rng.random() < 0.8:
                b.circle(float(q[0]), float(q[1]), r)
    for _ in range(int(rng.integers(1, 4))):  # tables and benches
        q = a + leg.direction * rng.uniform(1.0, length - 2.0) + n * rng.uniform(1.0, depth - 1.0)
        e = leg.direction * rng.uniform(0.6, 1.8) + n * rng.uniform(0.5, 0.9)
        lo, hi = np.minimum(q, q + e), np.maximum(q, q + e)
        b.box(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
