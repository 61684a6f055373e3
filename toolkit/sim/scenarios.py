"""The simulated places: the paper's test corridor and a Rawseeds-Bicocca-like building.

A scenario is a world (walls, glass, columns), a robot path through it (waypoints, driven at
`speed` with turns on the spot at `turn_rate`), and place zones, which give each scan its true
label. A label names a place the robot is AT, in the paper's sense of a place (window type A,
window type B, an open door; a corridor or a hall in a building): the laser is in the zone
while the feature is beside it, from a little before the feature until its far end passes the
scan plane (the beams see -90..90°, nothing behind), not while it is merely somewhere ahead
in the field of view. A place is something a user can teach from about ten scans of it.

Landmarks that are not places get no label of their own: the round columns along the
corridor's leg B are part of the wall the robot drives past (the scans beside them are plain
corridor, "none"), not somewhere the robot is.

corridor (the paper's Fig. 1), 2.4 m wide, metres, robot driving +x then +y:
    leg A, y in [-1.2, 1.2], x from 0 to 81.2: straight, parallel walls.
      left wall (y = +1.2): five small windows 0.8 m wide near the start (x 3..10.2,
      "window_a"), a 12 m long window in the middle (x 34..46, "window_b");
      right wall (y = -1.2): four open doors, 0.9 m, into 4 x 3 m rooms (x = 16, 26, 56, 66,
      "door").
    corner at (80, 0) ("corner": the laser from 0.8 m before the crossing until it leaves
      the crossing along leg B, see `corner_zone`).
    leg B, x from 78.8 (left wall) to the right wall, which curves progressively outwards
      (x = 81.2 + 2 (y/79)^2), y up to 80; round columns r = 0.25 m on the left wall every
      8 m (y = 10 .. 74): landmarks, not places (no label: "none").
    The path: (1, 0) -> (80, 0), turn left, -> (80, 79): 158 m, eight sections of equal
    scan count (2000 scans = 8 x 250, the paper's Table 1) at 0.4 m/s, 5 Hz.

building (Rawseeds Bicocca-like), a ring of 2 m corridors around a 38 x 22 m block:
    south corridor (y = 0) opens into a 16 x 10 m hall (x 12..28) with six columns, two
      tables ("hall"); east corridor (x = 40): a stairwell opening 3 m wide with a railing of
      balusters, one flight up, one down ("stairs"); north corridor (y = 24): windows in the
      outer wall, 1.5 m panes ("window"); west corridor (x = 0): three open doors into rooms
      ("door"); the ring's corners ("corner", from 0.5 m before each crossing until the
      laser leaves it); elsewhere "corridor".
    The path loops once round the ring and on into the hall again (144 m, loop closure),
    4000 scans at 0.6 m/s, turning at 0.3 rad/s (the median speed and a brisk turn of the real
    Bicocca ground truth, ../shared/data/real/rawseeds_bicocca_groundtruth): about 15 Hz.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from toolkit import se2
from toolkit.sim.geometry import GLASS, World, WorldBuilder

NONE = "none"


@dataclass
class Zone:
    """Laser positions (axis-aligned box) at which a feature is in view beside the robot."""

    label: str
    x0: float
    y0: float
    x1: float
    y1: float

    def contains(self, xy: np.ndarray) -> np.ndarray:
        x, y = xy[:, 0], xy[:, 1]
        return (x >= self.x0) & (x <= self.x1) & (y >= self.y0) & (y <= self.y1)


@dataclass
class Scenario:
    name: str
    world: World
    waypoints: np.ndarray  # (K, 2)
    zones: list[Zone]  # first match wins
    default_label: str = NONE
    scans: int = 2000
    speed: float = 0.4  # m/s
    turn_rate: float = 0.5  # rad/s, turns on the spot
    sections: int = 0  # equal parts of the log numbered 0..n-1 (0: none)
    laser: dict[str, float] = field(default_factory=dict)  # LaserModel overrides (mounting)
    t0: float = 1_700_000_000.0  # s, UNIX time of the first scan
    region_parts: dict[str, int] = field(default_factory=dict)  # spans per taught place

    def labels(self, positions: np.ndarray) -> np.ndarray:
        """The true place label at each laser position (S x 2 or more columns)."""
        out = np.full(len(positions), self.default_label, dtype=object)
        free = np.ones(len(positions), dtype=bool)
        for zone in self.zones:
            hit = free & zone.contains(positions[:, :2])
            out[hit] = zone.label
            free &= ~hit
        return out.astype(str)


def sample_path(
    waypoints: np.ndarray, scans: int, speed: float, turn_rate: float
) -> tuple[np.ndarray, np.ndarray]:
    """Robot poses (S x 3) at evenly spaced times along the waypoints, and those times (s).

    The robot drives each leg straight at `speed` and turns on the spot at `turn_rate`.
    """
    wp = np.asarray(waypoints, dtype=np.float64)
    legs = np.diff(wp, axis=0)
    heading = np.unwrap(np.arctan2(legs[:, 1], legs[:, 0]))
    lengths = np.hypot(legs[:, 0], legs[:, 1])
    # key states: arrive at waypoint k+1 with heading k, then turn to heading k+1
    xy = [wp[0]]
    th = [heading[0]]
    dt = [0.0]
    for k in range(len(legs)):
        xy.append(wp[k + 1])
        th.append(heading[k])
        dt.append(lengths[k] / speed)
        if k + 1 < len(legs):
            xy.append(wp[k + 1])
            th.append(heading[k + 1])
            dt.append(abs(heading[k + 1] - heading[k]) / turn_rate)
    key_t = np.cumsum(dt)
    key_xy, key_th = np.array(xy), np.array(th)
    times = np.linspace(0.0, key_t[-1], scans)
    return se2.interpolate(key_t, np.column_stack([key_xy, key_th]), times), times


def corridor() -> Scenario:
    """The paper's test corridor (Fig. 1): see the module docstring for the plan."""
    b = WorldBuilder()
    w = 1.2
    x_corner_out, x_corner_in = 81.2, 78.8
    # leg A
    b.segment((0.0, -w), (0.0, w))  # end wall
    small_windows = [(3.0 + 1.6 * i, 3.8 + 1.6 * i, "glass") for i in range(5)]
    long_window = [(34.0, 46.0, "glass")]
    b.wall((0.0, w), (x_corner_in, w), small_windows + long_window)
    doors_a = [16.0, 26.0, 56.0, 66.0]
    b.wall(
        (0.0, -w),
        (x_corner_out, -w),
        [(d - 0.45, d + 0.45, "door") for d in doors_a],
        outward=(0.0, -1.0),
    )
    # leg B: left wall straight, right wall curving outwards progressively
    length_b = 80.0
    b.segment((x_corner_in, w), (x_corner_in, length_b))
    ys = np.linspace(-w, length_b, 41)
    xs = x_corner_out + 2.0 * (np.clip(ys, 0.0, None) / 79.0) ** 2
    b.polyline(list(zip(xs.tolist(), ys.tolist(), strict=True)))
    b.segment((x_corner_in, length_b), (float(xs[-1]), length_b))  # end wall
    columns_b = np.arange(10.0, 75.0, 8.0)
    for y in columns_b:
        b.circle(x_corner_in + 0.2, float(y), 0.25)

    # zones hold the laser while the feature is in its view, beside it: from a little before
    # the feature until its far end passes the scan plane (beams at -90..90° see nothing behind)
    zones = [corner_zone((80.0, 0.0), w, (1.0, 0.0), lead=0.8)]
    zones += [Zone("window_a", 2.5, -w, 10.0, w)]
    zones += [Zone("window_b", 33.5, -w, 45.8, w)]
    zones += [Zone("door", d - 0.9, -w, d + 0.3, w) for d in doors_a]
    # the columns are no zone: a column in the wall is a landmark the robot passes, not a place
    return Scenario(
        name="corridor",
        world=b.build(),
        waypoints=np.array([(1.0, 0.0), (80.0, 0.0), (80.0, 79.0)]),
        zones=zones,
        scans=2000,
        speed=0.4,
        sections=8,
        laser={"mount_x": 0.16, "mount_z": 0.30},
    )


def building(laps: int = 1) -> Scenario:
    """A Rawseeds Bicocca-like floor: see the module docstring for the plan. `laps`: times
    round the ring before the last leg (the scans grow with the path, as far apart as in one
    lap), for logs that come back again and again."""
    b = WorldBuilder()
    # ring: outer walls x in [-1, 41], y in [-1, 25]; inner block x in [1, 39], y in [1, 23]
    hall_x0, hall_x1, hall_depth = 12.0, 28.0, 10.0
    b.wall((-1.0, -1.0), (41.0, -1.0), [(hall_x0 + 1.0, hall_x1 + 1.0, "gap")])  # south outer
    hall_y = -1.0 - hall_depth
    b.polyline([(hall_x0, -1.0), (hall_x0, hall_y), (hall_x1, hall_y), (hall_x1, -1.0)])
    for cx in (15.5, 20.0, 24.5):
        for cy in (-4.0, -8.0):
            b.circle(cx, cy, 0.3)
    b.box(16.9, -6.4, 18.6, -5.6)  # tables between the columns
    b.box(21.4, -6.4, 23.1, -5.6)
    # east outer wall with a stairwell opening y in [8, 11]
    b.wall((41.0, -1.0), (41.0, 25.0), [(9.0, 12.0, "gap")])
    b.polyline([(41.0, 8.0), (45.0, 8.0), (45.0, 11.0), (41.0, 11.0)])
    b.segment((41.6, 9.5), (41.6, 11.0))  # the up flight's risers above laser height
    for x in np.arange(41.2, 45.0, 0.15):
        b.circle(float(x), 9.5, 0.025)  # railing balusters between the flights
    # north outer wall with windows x in [8, 32]
    panes = [(9.0 + 2.0 * i, 10.5 + 2.0 * i, "glass") for i in range(12)]
    b.wall((-1.0, 25.0), (41.0, 25.0), panes)
    # west outer wall with doors into rooms
    doors_w = [18.0, 12.0, 6.0]
    b.wall(
        (-1.0, -1.0),
        (-1.0, 25.0),
        [(d + 1.0 - 0.45, d + 1.0 + 0.45, "door") for d in doors_w],
        outward=(-1.0, 0.0),
    )
    b.polyline([(1.0, 1.0), (39.0, 1.0), (39.0, 23.0), (1.0, 23.0), (1.0, 1.0)])  # inner block

    # driving round the ring: north into (0, 0), east into (40, 0), and so on
    arrivals = [(0.0, -1.0), (1.0, 0.0), (0.0, 1.0), (-1.0, 0.0)]
    zones = [corner_zone(c, 1.0, a, lead=0.5) for c, a in zip(_ring(), arrivals, strict=True)]
    zones += [Zone("hall", hall_x0 - 0.5, -1.0, hall_x1 - 0.2, 1.0)]  # driving +x
    zones += [Zone("stairs", 39.0, 7.5, 41.0, 10.8)]  # driving +y
    zones += [Zone("window", 8.2, 23.0, 32.0, 25.0)]  # driving -x
    zones += [Zone("door", -1.0, d - 0.3, 1.0, d + 0.9) for d in doors_w]  # driving -y
    lap = [*_ring()[1:], (0.0, 0.0)]  # from (4, 0) round the ring and back to (0, 0)
    return Scenario(
        name="building",
        world=b.build(),
        waypoints=np.array([(4.0, 0.0), *lap * laps, (20.0, 0.0)]),
        zones=zones,
        default_label="corridor",
        scans=round(4000 * (144.0 + 128.0 * (laps - 1)) / 144.0),  # path 144 m, 128 m a lap more
        speed=0.6,
        turn_rate=0.3,
        sections=0,
        laser={"mount_x": 0.08, "mount_z": 0.45},
    )


def corner_zone(
    centre: tuple[float, float], half_width: float, arriving: tuple[float, float], lead: float
) -> Zone:
    """The corner as a place: the laser within the crossing of two corridors (a square of
    `half_width` round `centre`), and `lead` metres before it on the side the robot arrives
    from. It ends where the crossing's far side passes the scan plane on the way out, as
    every zone does: a metre further on the robot is in the next corridor and sees only it."""
    (cx, cy), (ax, ay) = centre, arriving
    x0, x1 = cx - half_width - lead * (ax > 0), cx + half_width + lead * (ax < 0)
    y0, y1 = cy - half_width - lead * (ay > 0), cy + half_width + lead * (ay < 0)
    return Zone("corner", x0, y0, x1, y1)


def _ring() -> list[tuple[float, float]]:
    return [(0.0, 0.0), (40.0, 0.0), (40.0, 24.0), (0.0, 24.0)]


SCENARIOS = {"corridor": corridor, "building": building}

__all__ = ["GLASS", "SCENARIOS", "Scenario", "Zone", "building", "corridor", "sample_path"]
