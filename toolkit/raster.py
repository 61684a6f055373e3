"""Maps as pictures: every return of a log placed in the world (`world_points`) and
counted into a pixel grid, the trajectory drawn over it; one pass over the returns, so that
map.png costs about as much as reading the scans. The counting is a numba kernel that places
and counts each return in one step (no N x 2 temporaries), with the same arithmetic as
`world_points` (the same pixels); numba is loaded by every command that draws a map anyway
(the matcher's and the occupancy grid's kernels)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numba as nb
import numpy as np

from toolkit import se2
from toolkit.dataset import Dataset, LaserGeometry
from toolkit.writers import write_png

CHUNK = 20_000  # scans per chunk of map building


def world_points(
    ranges: np.ndarray, robot: np.ndarray, laser: LaserGeometry
) -> tuple[np.ndarray, np.ndarray]:
    """Every return of `ranges` (S x B) in world x, y (N x 2) and the scan it came from (N,)."""
    lp = se2.laser_poses(robot, laser)
    finite = np.isfinite(ranges)
    scan = np.repeat(np.arange(len(ranges)), np.count_nonzero(finite, axis=1))
    r = ranges[finite].astype(np.float64)
    # each beam's direction turned by its scan's heading: products of per-scan and per-beam
    # cosines and sines (no trigonometry per return), laid out S x B and then masked
    c, s = np.cos(lp[:, 2])[:, None], np.sin(lp[:, 2])[:, None]
    ca, sa = np.cos(laser.angles), np.sin(laser.angles)
    xy = np.empty((len(r), 2))
    xy[:, 0] = (c * ca - s * sa)[finite] * r + lp[scan, 0]
    xy[:, 1] = (s * ca + c * sa)[finite] * r + lp[scan, 1]
    return xy, scan


BeamFrame = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def beam_frame(robot: np.ndarray, laser: LaserGeometry) -> BeamFrame:
    """What `return_xy` needs to place the returns of scans at `robot` (S x 3): the laser
    poses, their headings' cosines and sines, and the beams' cosines and sines."""
    lp = se2.laser_poses(robot, laser)
    return lp, np.cos(lp[:, 2]), np.sin(lp[:, 2]), np.cos(laser.angles), np.sin(laser.angles)


@nb.njit(inline="always")
def return_xy(frame: BeamFrame, k: int, b: int, r: float) -> tuple[float, float]:
    """Return `r` of beam `b` of scan `k` in world x, y, in compiled kernels: `world_points`'
    operations in the same order, so the same bits."""
    lp, c, s, ca, sa = frame
    x = (c[k] * ca[b] - s[k] * sa[b]) * r + lp[k, 0]
    y = (s[k] * ca[b] + c[k] * sa[b]) * r + lp[k, 1]
    return x, y


def scan_chunks(n: int, chunk: int) -> Iterator[slice]:
    for lo in range(0, n, chunk):
        yield slice(lo, min(lo + chunk, n))


TRAJECTORY_RGB = (215, 25, 28)
TRUTH_RGB = (26, 150, 65)


def map_image(
    ds: Dataset,
    robot: np.ndarray,
    truth: np.ndarray | None,
    lo: np.ndarray,
    cell: float,
    size: tuple[int, int],
    chunk: int = CHUNK,
) -> np.ndarray:
    """Top view (height x width x 3, row 0 the largest y): every return counted into a pixel
    grid of `cell` m from corner `lo` (grey, log-scaled, white where none), the trajectory
    over it in red and the ground truth dashed in green. One pass over the returns, chunk by
    chunk: memory does not grow with the log."""
    width, height = size
    counts = np.zeros(width * height, np.int64)
    origin = np.asarray(lo, np.float64)
    for part in scan_chunks(ds.n_scans, chunk):
        frame = beam_frame(robot[part], ds.laser)
        _count_returns(ds.ranges[part], frame, origin, float(cell), width, counts)
    hit = np.flatnonzero(counts)
    shade = np.log1p(counts[hit].astype(np.float64))
    top = float(np.percentile(shade, 95)) if len(shade) else 1.0
    grey = np.full(width * height, 255, np.uint8)
    grey[hit] = np.round(255.0 * (1.0 - np.minimum(shade / top, 1.0)))
    image = np.empty((height, width, 3), np.uint8)
    image[:] = grey.reshape(height, width)[::-1, :, None]
    if truth is not None:
        _draw_path(image, truth[:, :2], lo, cell, TRUTH_RGB, dash=8)
    _draw_path(image, robot[:, :2], lo, cell, TRAJECTORY_RGB)
    return image


@nb.njit(cache=True, nogil=True)
def _count_returns(
    ranges: np.ndarray,
    frame: BeamFrame,
    lo: np.ndarray,
    cell: float,
    width: int,
    counts: np.ndarray,
) -> None:
    """Add every finite return of `ranges` (S x B) to `counts` (height x width, flat, row =
    y): placed by `return_xy` (as `world_points` places it), in pixels of `cell` m from
    corner `lo`; returns outside the grid are left out."""
    height = counts.shape[0] // width
    for k in range(ranges.shape[0]):
        for b in range(ranges.shape[1]):
            r = np.float64(ranges[k, b])
            if not math.isfinite(r):
                continue
            x, y = return_xy(frame, k, b, r)
            i = math.floor((x - lo[0]) / cell)
            j = math.floor((y - lo[1]) / cell)
            if 0 <= i < width and 0 <= j < height:
                counts[j * width + i] += 1


def returns_box(
    ranges: np.ndarray, robot: np.ndarray, laser: LaserGeometry, reach: float = np.inf
) -> tuple[np.ndarray, np.ndarray] | None:
    """Lower and upper corner (x, y) of the returns of `ranges` (S x B) within `reach` of
    the laser, placed as `world_points` places them (the same values, without its N x 2
    array); None when there is none."""
    box = np.array([np.inf, np.inf, -np.inf, -np.inf])
    n = _box_returns(ranges, beam_frame(robot, laser), reach, box)
    return (box[:2], box[2:]) if n else None


@nb.njit(cache=True, nogil=True)
def _box_returns(
    ranges: np.ndarray,
    frame: BeamFrame,
    reach: float,
    box: np.ndarray,
) -> int:
    """Widen `box` (x min, y min, x max, y max) to the finite returns within `reach`; their
    number."""
    n = 0
    for k in range(ranges.shape[0]):
        for b in range(ranges.shape[1]):
            r = np.float64(ranges[k, b])
            if not (math.isfinite(r) and r <= reach):
                continue
            x, y = return_xy(frame, k, b, r)
            box[0], box[1] = min(box[0], x), min(box[1], y)
            box[2], box[3] = max(box[2], x), max(box[3], y)
            n += 1
    return n


def grid_for(
    ds: Dataset, robot: np.ndarray, cells: int = 1500, chunk: int = CHUNK
) -> tuple[np.ndarray, float, tuple[int, int]]:
    """The corner, pixel size and (width, height) of a map of `ds` along `robot`: at most
    `cells` pixels along the longer side, at least 2 cm a pixel."""
    lo, hi = _extent(ds, robot, chunk)
    cell = max(float((hi - lo).max()) / cells, 0.02)
    width, height = np.maximum(np.ceil((hi - lo) / cell).astype(np.int64), 1)
    return lo, cell, (int(width), int(height))


def map_text(title: str, lo: np.ndarray, cell: float, panels: str = "") -> dict[str, str]:
    """The PNG text of a map: what it shows, and the grid's resolution and origin."""
    return {
        "Title": title,
        "Description": f"{panels}laser returns (grey, log scale), trajectory (red), ground "
        "truth (green, dashed); x to the right, y up",
        "resolution": f"{cell:.6g}",
        "origin": f"{lo[0]:.6g} {lo[1]:.6g}",
    }


def write_map_png(
    path: Path,
    ds: Dataset,
    robot: np.ndarray,
    truth: np.ndarray | None = None,
    title: str = "",
    chunk: int = CHUNK,
    cells: int = 1500,
) -> None:
    """map.png: the top view of `map_image` on the grid of `grid_for`; the grid's resolution
    and origin go into the PNG's text (`resolution`, `origin`)."""
    lo, cell, size = grid_for(ds, robot, cells, chunk)
    write_png(path, map_image(ds, robot, truth, lo, cell, size, chunk), map_text(title, lo, cell))


def _extent(ds: Dataset, robot: np.ndarray, chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corner (x, y) of the map: the 0.5-99.5 percentiles of the returns of
    every few scans (at most ~200,000 returns), widened to hold the trajectory plus 1 m."""
    returns = sum(
        np.count_nonzero(np.isfinite(ds.ranges[p])) for p in scan_chunks(ds.n_scans, chunk)
    )
    step = max(1, -(-int(returns) // 200_000))
    xy, _ = world_points(ds.ranges[::step], robot[::step], ds.laser)
    if len(xy):
        lo, hi = np.percentile(xy, 0.5, axis=0), np.percentile(xy, 99.5, axis=0)
    else:
        lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    if len(robot):
        lo = np.minimum(lo, robot[:, :2].min(axis=0) - 1)
        hi = np.maximum(hi, robot[:, :2].max(axis=0) + 1)
    if not np.isfinite(lo).all() or not np.isfinite(hi).all():
        return np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    return lo, hi


def _draw_path(
    image: np.ndarray,
    xy: np.ndarray,
    lo: np.ndarray,
    cell: float,
    rgb: tuple[int, int, int],
    dash: int = 0,
) -> None:
    """Draw the polyline `xy` (m) into `image` (row 0 at the top), 2 pixels wide: points every
    half pixel along it; `dash` > 0 leaves gaps of that many pixels."""
    xy = xy[np.isfinite(xy).all(axis=1)]
    if len(xy) == 0:
        return
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    s = np.arange(0.0, along[-1] + cell / 2, cell / 2)
    if dash > 0:
        s = s[(s // (dash * cell)).astype(np.int64) % 2 == 0]
    px = (np.interp(s, along, xy[:, 0]) - lo[0]) / cell
    py = (np.interp(s, along, xy[:, 1]) - lo[1]) / cell
    height, width = image.shape[:2]
    for di in (0, 1):
        for dj in (0, 1):
            i = np.floor(px).astype(np.int64) + di
            row = height - 1 - (np.floor(py).astype(np.int64) + dj)
            ok = (i >= 0) & (i < width) & (row >= 0) & (row < height)
            image[row[ok], i[ok]] = rgb
