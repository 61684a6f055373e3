"""Map outputs of the mapper: the occupancy grid (ROS map_server's map.pgm + map.yaml) and the
side-by-side map.png (odometry / before loops / after loops).

Occupancy: every beam is traced from the laser to its return through the grid (numba,
Bresenham per beam, over chunks of scans): the cells it crosses count a miss, the cell of the
return a hit (a beam without return counts misses up to `free_range`). A cell seen hit in at
least `occupied` of its observations is occupied (0, black), one observed and below `free`
is free (254, white), the rest unknown (205), as map_server's trinary mode reads them with
the yaml's thresholds.

Consistency (`grid_consistency`, without a truth), from the same grid: the share of the
returns that land where the grid shows no obstacle within one cell (other beams crossed those
cells more often than they ended there: the ray conflicts of Mazuran et al. 2014, counted on
the grid), and the cells holding a return per 1000 returns (a doubled or blurred wall takes
more cells: the grid's analogue of Razlaw et al. 2015's mean map entropy).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numba as nb
import numpy as np

from toolkit import se2
from toolkit.dataset import Dataset
from toolkit.metrics import align_se2
from toolkit.raster import CHUNK, grid_for, map_image, map_text, returns_box, scan_chunks
from toolkit.writers import write_png

#: the occupancy counts are traced in two threads, each into its own grid, only while the
#: second grid's hits and observations take at most this many bytes
SPLIT_BYTES = 64 * 2**20


def _bounds(ds: Dataset, robot: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of the trajectory (plus 1 m) and of the returns within `reach` of the
    laser (`returns_box`: one pass, no N x 2 array)."""
    lo = robot[:, :2].min(axis=0) - 1.0
    hi = robot[:, :2].max(axis=0) + 1.0
    box = returns_box(ds.ranges, robot, ds.laser, reach)
    if box is not None:
        lo, hi = np.minimum(lo, box[0]), np.maximum(hi, box[1])
    return lo, hi


@nb.njit(cache=True, nogil=True)
def _trace(
    lp: np.ndarray,
    ranges: np.ndarray,
    angles: np.ndarray,
    lo: np.ndarray,
    res: float,
    reach: float,
    free_range: float,
    hits: np.ndarray,
    seen: np.ndarray,
) -> None:
    h, w = hits.shape
    flat = seen.reshape(-1)
    for k in range(lp.shape[0]):
        x0 = (lp[k, 0] - lo[0]) / res
        y0 = (lp[k, 1] - lo[1]) / res
        for b in range(angles.shape[0]):
            r = ranges[k, b]
            hit = r == r and r <= reach
            length = r if hit else free_range
            if not (length > 0):
                continue
            th = lp[k, 2] + angles[b]
            x1 = x0 + length * math.cos(th) / res
            y1 = y0 + length * math.sin(th) / res
            i0, j0 = math.floor(x0), math.floor(y0)
            i1, j1 = math.floor(x1), math.floor(y1)
            di, dj = abs(i1 - i0), abs(j1 - j0)
            si = 1 if i1 > i0 else -1
            sj = 1 if j1 > j0 else -1
            err = di - dj
            if 0 <= i0 < w and 0 <= j0 < h and 0 <= i1 < w and 0 <= j1 < h:
                # both ends on the grid, so every cell between (the steps go monotonically
                # from one to the other): no bounds checks, one flat index. The loop below
                # (kept for beams that leave the grid) steps the major axis every time, the
                # longer of di, dj (with di >= dj, 2 err > -dj holds throughout; with
                # dj > di, 2 err < di), so it visits max(di, dj) cells before the end: here
                # as a count with the minor step's test alone, on e = -err when y is the
                # major axis and doubled (the same cells; 40% faster, no branch to mispredict)
                if di >= dj:
                    da, db, step_a, step_b = di, dj, si, sj * w
                else:
                    da, db, step_a, step_b = dj, di, sj * w, si
                at = j0 * w + i0
                e, da2, db2 = 2 * (da - db), 2 * da, 2 * db
                for _ in range(da):
                    flat[np.uint64(at)] += 1  # at >= 0: no negative-index wrap
                    minor = e < da
                    e += (da2 if minor else 0) - db2
                    at += step_a + (step_b if minor else 0)
            else:
                i, j = i0, j0
                for _ in range(di + dj + 1):
                    if i == i1 and j == j1:
                        break
                    if 0 <= i < w and 0 <= j < h:
                        seen[j, i] += 1
                    e2 = 2 * err
                    if e2 > -dj:
                        err -= dj
                        i += si
                    if e2 < di:
                        err += di
                        j += sj
            if hit and 0 <= i1 < w and 0 <= j1 < h:
                hits[j1, i1] += 1
                seen[j1, i1] += 1


def occupancy(
    ds: Dataset,
    robot: np.ndarray,
    resolution: float = 0.05,
    reach: float = 30.0,
    free_range: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hit and observation counts per cell (H x W, row = y) and the grid's origin (lower-left)."""
    lo, hi = _bounds(ds, robot, reach)
    lo = np.floor(lo / resolution) * resolution
    shape = np.ceil((hi - lo) / resolution).astype(np.int64) + 1
    hits = np.zeros((shape[1], shape[0]), dtype=np.int32)
    seen = np.zeros_like(hits)
    angles = ds.laser.angles.astype(np.float64)

    def trace(parts: list[slice], hits: np.ndarray, seen: np.ndarray) -> None:
        for part in parts:
            lp = se2.laser_poses(robot[part], ds.laser)
            _trace(lp, ds.ranges[part], angles, lo, resolution, reach, free_range, hits, seen)

    parts = list(scan_chunks(ds.n_scans, min(CHUNK, max(-(-ds.n_scans // 2), 1))))
    if len(parts) < 2 or 2 * hits.nbytes > SPLIT_BYTES:
        trace(parts, hits, seen)
        return hits, seen, lo
    # two threads (the kernel releases the GIL), each counting into its own grid: counts
    # add up to the same integers whatever the order
    other = (np.zeros_like(hits), np.zeros_like(seen))
    with ThreadPoolExecutor(2) as pool:
        done = [
            pool.submit(trace, parts[0::2], hits, seen),
            pool.submit(trace, parts[1::2], *other),
        ]
        for future in done:
            future.result()
    hits += other[0]
    seen += other[1]
    return hits, seen, lo


@nb.njit(cache=True, nogil=True)
def _classify(
    hits: np.ndarray, seen: np.ndarray, occupied: float, free: float, img: np.ndarray
) -> None:
    """map.pgm's value per cell into `img` (filled with 205, unknown): 0 where the hit ratio
    is at least `occupied`, else 254 where it is under `free` (one pass, no ratio array)."""
    h, w = hits.shape
    for j in range(h):
        for i in range(w):
            s = seen[j, i]
            if s > 0:
                ratio = hits[j, i] / s
                if ratio >= occupied:
                    img[j, i] = 0
                elif ratio < free:
                    img[j, i] = 254


@nb.njit(cache=True, nogil=True)
def _conflicts(hits: np.ndarray, img: np.ndarray) -> tuple[int, int, int]:
    """The returns, those with no 0 (occupied) in `img` among the 3 x 3 cells around theirs,
    and the cells holding a return."""
    h, w = hits.shape
    total = conflict = cells = 0
    for j in range(h):
        for i in range(w):
            n = hits[j, i]
            if n == 0:
                continue
            total += n
            cells += 1
            near = False
            for jj in range(max(j - 1, 0), min(j + 2, h)):
                for ii in range(max(i - 1, 0), min(i + 2, w)):
                    near |= img[jj, ii] == 0
            if not near:
                conflict += n
    return total, conflict, cells


def grid_consistency(hits: np.ndarray, img: np.ndarray) -> dict[str, float | int | None]:
    """How well the scans agree with each other at these poses, from the occupancy grid alone
    (no truth): `conflict`, the share of the returns with no occupied cell (0 in `img`, H x W:
    map.pgm's values, rows as `hits`) among the 3 x 3 cells around theirs: returns that other
    beams crossed more often than they ended there; `cells`, the cells that hold a return per
    1000 returns (a doubled or blurred wall spreads its returns over more cells); `returns`,
    how many. Lower is more consistent; comparable only between poses of one log (docs/maps.md).
    None without returns. The neighbourhood makes the figure nearly blind to how the walls lie
    on the grid; a cell's own hit ratio is not (beams grazing a wall that runs along a row of
    cells cross the wall's cells)."""
    total, conflict, cells = _conflicts(hits, img)
    if total == 0:
        return {"conflict": None, "cells": None, "returns": 0}
    return {
        "conflict": round(conflict / total, 5),
        "cells": round(1000.0 * cells / total, 3),
        "returns": int(total),
    }


def map_consistency(
    ds: Dataset, robot: np.ndarray, resolution: float = 0.05, occupied: float = 0.25
) -> dict[str, float | int | None]:
    """`grid_consistency` of the scans of `ds` at `robot` (poses of any source: another
    mapper's, the odometry, a truth), on the grid `write_occupancy` would write."""
    hits, seen, _ = occupancy(ds, robot, resolution)
    img = np.full(hits.shape, 205, dtype=np.uint8)
    _classify(hits, seen, occupied, 0.0, img)  # free cells play no part
    return grid_consistency(hits, img)


def write_occupancy(
    out: Path,
    ds: Dataset,
    robot: np.ndarray,
    resolution: float = 0.05,
    occupied: float = 0.25,
    free: float = 0.1,
) -> tuple[dict[str, object], dict[str, float | int | None]]:
    """`map.pgm` (binary P5, 0 occupied, 254 free, 205 unknown; top row = largest y) and
    `map.yaml` for ROS map_server in `out`; returns the yaml's fields and the grid's
    `grid_consistency` (from the same counts: no second trace)."""
    hits, seen, lo = occupancy(ds, robot, resolution)
    img = np.full(hits.shape, 205, dtype=np.uint8)
    _classify(hits, seen, occupied, free, img)
    figure = grid_consistency(hits, img)
    img = np.ascontiguousarray(img[::-1])  # PGM's first row is the top: the largest y
    h, w = hits.shape
    with open(out / "map.pgm", "wb") as f:
        f.write(f"P5\n# laser-toolkit occupancy grid\n{w} {h}\n255\n".encode("ascii"))
        f.write(img.tobytes())
    meta: dict[str, object] = {
        "image": "map.pgm",
        "mode": "trinary",
        "resolution": resolution,
        "origin": [float(lo[0]), float(lo[1]), 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    text = "".join(f"{k}: {_yaml(v)}\n" for k, v in meta.items())
    (out / "map.yaml").write_text(text)
    return meta, figure


def _yaml(v: object) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(repr(float(x)) for x in v) + "]"
    return str(v)


def read_pgm(path: Path) -> np.ndarray:
    """A binary PGM (P5, 8 bit) as an array (rows top to bottom)."""
    data = Path(path).read_bytes()
    fields: list[bytes] = []
    pos = 0
    while len(fields) < 4:
        while data[pos : pos + 1].isspace():
            pos += 1
        if data[pos : pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end : end + 1].isspace():
            end += 1
        fields.append(data[pos:end])
        pos = end
    if fields[0] != b"P5":
        raise ValueError(f"{path}: not a binary PGM")
    w, h = int(fields[1]), int(fields[2])
    return np.frombuffer(data[pos + 1 : pos + 1 + w * h], dtype=np.uint8).reshape(h, w)


def write_side_by_side(
    path: Path,
    ds: Dataset,
    panels: list[tuple[str, np.ndarray]],
    truth: np.ndarray | None = None,
    title: str = "",
    cells: int = 800,
) -> None:
    """map.png: one top view per (name, robot poses) panel, left to right, each aligned to
    the last panel's frame, with its trajectory (and the truth, dashed, aligned to it), on one
    pixel grid; the panels' names, in order, go into the PNG's text."""
    ref = panels[-1][1]
    moved = []
    for name, poses in panels:
        T = align_se2(poses, ref) if poses is not ref else np.zeros(3)
        moved.append((name, se2.compose(np.broadcast_to(T, poses.shape), poses)))
    if truth is not None:
        truth = se2.compose(np.broadcast_to(align_se2(truth, ref), truth.shape), truth)
    lo, cell, size = grid_for(ds, ref, cells)
    gap = np.full((size[1], 12, 3), 255, np.uint8)
    images: list[np.ndarray] = []
    for _, poses in moved:
        images += [map_image(ds, poses, truth, lo, cell, size), gap]
    names = " | ".join(name for name, _ in moved)
    text = map_text(title, lo, cell, panels=f"left to right: {names}; ")
    write_png(path, np.concatenate(images[:-1], axis=1), text)
