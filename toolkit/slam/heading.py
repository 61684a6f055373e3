"""The heading of a log without odometry, refined against a small local map.

The keyframe front end (`toolkit.slam.localmap`) matches each scan against one keyframe and
chains the keyframes: a heading error of a few hundredths of a degree per match adds up, and a
scanner that turns fast makes a keyframe every second scan (the CCNY hand-held bag: 5.7 deg in
36 s, walls doubled; journal, session 27). Scan-to-map matching does not drift so, but its
translation along a corridor is worse without odometry (the keyframe front end's forward probe
has no counterpart there). So `HeadingMap` keeps the keyframe front end's translation and
fits only the heading against the surfaces of its last keyframes (their poses as refined), on
scan-to-map's truncated distance grid (`toolkit.slam.scanmap`'s surfaces and Gauss-Newton fit,
the translation held by a prior of 1e12): the heading is what every wall observes, also along
a corridor. A fit that few returns agree with, or that turns the heading more than
`MAX_TURN`, is not taken (the map does not cover the scan, or the fit slid).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from toolkit import se2
from toolkit.dataset import LaserGeometry
from toolkit.slam.grid import bounds, stamp_segments
from toolkit.slam.scanmap import _OUT, MapConfig, _fit, _scan_points, surfaces

HOLD = 1e12  # the translation's prior information (1 / m^2): held
HEADING_SIGMA = 0.05  # rad: the front end's heading as a prior (loose: the map decides)
MIN_SHARE = 0.5  # a fit with fewer of its returns within `inlier_distance` of the map is left
MAX_TURN = 0.05  # rad: a fit that turns the heading further is left (a slide, not a drift)
ITERATIONS = 20  # most Gauss-Newton rounds of a heading fit (10: 0.47 deg apart on the bag)
MARGIN = 5.0  # m around the map's surfaces when its grid is built: new keyframes fit in
REACH = 2.0  # ... and at most this many times the map's range (max_range + map_margin) from
# the robot each way (120 m square, 23 MB, at scan-to-map's 25 + 5 m)


class HeadingMap:
    """The last `keys` to 2 `keys` keyframes' surfaces on a distance grid (rebuilt from the
    last `keys` once there are twice as many, or once a new keyframe leaves the grid):
    `refine(ranges, pose)` returns `pose` with its heading fitted to them, `add(ranges, pose)`
    takes a keyframe. The grid's cell, cap, the surfaces and the fit's constants are
    `config`'s (scan-to-map's)."""

    def __init__(self, laser: LaserGeometry, keys: int, config: MapConfig | None = None) -> None:
        self.laser = laser
        self.keys = max(int(keys), 1)
        self.config = config or MapConfig()
        self._keys: deque[np.ndarray] = deque()  # placed segments, N x 4
        self._grid: tuple[np.ndarray, np.ndarray] | None = None  # origin, distances
        self._hi = np.zeros(2)  # the grid's far corner
        mount = se2.mount_pose(laser)
        self._mount = mount
        self._cos = np.cos(laser.angles + mount[2])
        self._sin = np.sin(laser.angles + mount[2])
        self._info = np.array([HOLD, HOLD, 1.0 / HEADING_SIGMA**2])
        self.refined = 0  # scans whose heading the map moved
        self.turned = 0.0  # rad: the sum of those moves

    def add(self, ranges: np.ndarray, pose: np.ndarray) -> None:
        """Take a keyframe: its surfaces placed at `pose` stamped into the grid, or the grid
        rebuilt around the last `keys` keyframes."""
        cfg = self.config
        seg = surfaces(ranges, self.laser, cfg, pose, (self._cos, self._sin, self._mount))
        self._keys.append(seg)
        grid = self._grid
        if grid is not None and len(self._keys) < 2 * self.keys and self._covers(seg):
            stamp_segments(grid[1], grid[0], cfg.resolution, seg, cfg.cap)
            return
        while len(self._keys) > self.keys:
            self._keys.popleft()
        every = np.concatenate(list(self._keys))
        ends = np.concatenate([every[:, :2], every[:, 2:], np.asarray(pose)[None, :2]])
        lo, hi = bounds(ends)
        # at most `REACH` m from the robot: a trajectory lost far and wide (a CARMEN log
        # without its odometry) would ask for hundreds of metres of 5 cm cells
        reach = REACH * (cfg.max_range + cfg.map_margin)
        lo = np.maximum(lo - MARGIN, np.asarray(pose)[:2] - reach)
        hi = np.minimum(hi + MARGIN, np.asarray(pose)[:2] + reach)
        shape = np.ceil((hi - lo) / cfg.resolution).astype(np.int64)
        dist = np.full((int(shape[1]), int(shape[0])), cfg.cap, dtype=np.float32)
        for q in self._keys:
            stamp_segments(dist, lo, cfg.resolution, q, cfg.cap)
        self._grid = (lo, dist)
        self._hi = lo + shape * cfg.resolution

    def _covers(self, seg: np.ndarray) -> bool:
        """Whether the grid holds every end of `seg` with the cap to spare."""
        assert self._grid is not None
        if len(seg) == 0:
            return True
        cap = self.config.cap
        xs, ys = seg[:, 0::2], seg[:, 1::2]
        lo = self._grid[0]
        return bool(
            xs.min() - cap >= lo[0]
            and ys.min() - cap >= lo[1]
            and xs.max() + cap <= self._hi[0]
            and ys.max() + cap <= self._hi[1]
        )

    def refine(self, ranges: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """`pose` (robot, world) with its heading fitted to the map, its translation held;
        `pose` itself when there is no map yet, too few returns agree, or the fit turned
        further than `MAX_TURN`."""
        if self._grid is None:
            return pose
        cfg = self.config
        pts = _scan_points(
            np.asarray(ranges), self._cos, self._sin, self._mount[0], self._mount[1], cfg.max_range
        )
        if len(pts) < 3:
            return pose
        start = np.asarray(pose, dtype=np.float64)
        out = np.zeros(_OUT)
        _fit(
            self._grid[1],
            self._grid[0],
            cfg.resolution,
            pts,
            start,
            start,
            self._info,
            ITERATIONS,
            cfg.gate,
            cfg.sigma_min,
            cfg.inlier_distance,
            cfg.degenerate,
            cfg.min_information,
            out,
            np.zeros((3, 3)),
        )
        turn = math.atan2(math.sin(out[2] - start[2]), math.cos(out[2] - start[2]))
        if out[4] < MIN_SHARE or abs(turn) > MAX_TURN:
            return pose
        self.refined += 1
        self.turned += abs(turn)
        return np.array([start[0], start[1], out[2]])


__all__ = ["HeadingMap"]
