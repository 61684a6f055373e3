"""Likelihood grids and the correlative search that matches points against them.

A likelihood grid rasterises a set of map points (the returns of some keyframes, in one
frame) and stores, per cell, exp(-d^2 / 2 sigma^2) of the distance d to the nearest map point
(scipy's exact Euclidean distance transform): a query point's fit is one O(1) lookup, so
scoring a pose is O(N) in the query's points, with no tree and no neighbour search.

`correlative_search` scores every pose of a grid of (heading, x, y) offsets around a
prediction (numba, one heading after another), coarse to fine: a coarse grid over the whole
window, then a fine grid around the coarse maxima. It needs no good seed, only the window.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numba as nb
import numpy as np


def _edt() -> Callable[..., np.ndarray]:
    """scipy's exact Euclidean distance transform, imported on first use: scipy.ndimage
    costs 0.1-0.2 s to import, and many map runs never need it (the wide grids' transform:
    none in `toolkit map` on the simulated 5,000-scan building)."""
    from scipy.ndimage import distance_transform_edt  # noqa: PLC0415

    return distance_transform_edt  # type: ignore[no-any-return]


_DISC_CELLS = 16  # `LikelihoodGrid.build` stamps discs up to this radius (cells)


@dataclass(frozen=True)
class LikelihoodGrid:
    """Per cell, the likelihood of a point there given the map points (row = y, col = x)."""

    origin: np.ndarray  # (2,) world x, y of cell (0, 0)'s lower-left corner
    resolution: float  # m per cell
    likelihood: np.ndarray  # H x W float32 in [0, 1]
    likelihood_t: np.ndarray  # its transpose, contiguous (W x H): the search's layout
    distance: np.ndarray  # H x W float32: distance (m) to the nearest map point, capped

    @classmethod
    def build(
        cls,
        points: np.ndarray,
        resolution: float,
        sigma: float,
        margin: float = 1.0,
        cap: float = 2.0,
    ) -> LikelihoodGrid:
        """The grid of `points` (N x 2, finite) with `margin` m around their bounding box.

        Distances within the cap are stamped around each occupied cell (`_disc_field`, from
        tables of the distance transform's own values by squared cell distance) when the cap
        is at most `_DISC_CELLS` cells, else by scipy's distance transform: the same grid to
        the bit either way (the cells beyond the disc are beyond the cap in both), the first
        a fraction of the transform's time on the coarse grids the searches use."""
        lo, shape, ij = _raster(points, resolution, margin)
        r = math.ceil(cap / resolution)
        if r <= _DISC_CELLS:
            # squared cell distances 0 .. r*r (the disc), then one entry for beyond it
            dist_of = np.minimum(np.sqrt(np.arange(r * r + 2, dtype=np.float64)) * resolution, cap)
            dist_of = dist_of.astype(np.float32)
            dist_of[-1] = cap  # sqrt(r*r + 1) * resolution > cap
            like_of = np.exp(-(dist_of.astype(np.float64) ** 2) / (2 * sigma * sigma))
            cells = np.ascontiguousarray(ij)
            like_of = like_of.astype(np.float32)
            dist, like_t = _disc_field(cells, int(shape[1]), int(shape[0]), r, dist_of, like_of)
            return cls(lo, resolution, np.ascontiguousarray(like_t.T), like_t, dist)
        free = np.ones((shape[1], shape[0]), dtype=bool)
        free[ij[:, 1], ij[:, 0]] = False
        distance_transform_edt = _edt()
        dist = np.minimum(distance_transform_edt(free) * resolution, cap).astype(np.float32)
        like = np.exp(-(dist.astype(np.float64) ** 2) / (2 * sigma * sigma)).astype(np.float32)
        return cls(lo, resolution, like, np.ascontiguousarray(like.T), dist)

    @classmethod
    def window(
        cls,
        points: np.ndarray,
        resolution: float,
        sigma: float,
        lo: np.ndarray,
        hi: np.ndarray,
        margin: float = 1.0,
        cap: float = 2.0,
        pad: float = 0.6,
    ) -> LikelihoodGrid:
        """The part of `build(points, resolution, sigma, margin, cap)`'s grid that covers the
        box `lo`-`hi`, the same cells (same origin and rasterisation) and, within `pad` m of
        a point, the same values to the bit (the distance transform's: cell to nearest
        occupied cell); farther cells get the cap (likelihood 0, where `build`'s is below
        exp(-pad^2/2 sigma^2), nil). Each occupied cell stamps the disc of cells within `pad`
        (numba) instead of a distance transform of the whole map: a correlative search's fine
        level needs only where the query lands, and the whole map at the fine resolution was
        most of a loop test's time."""
        full_lo, shape, ij = _raster(points, resolution, margin)
        n_pad = math.ceil(pad / resolution) + 1
        i0 = np.maximum(
            np.floor((np.asarray(lo) - full_lo) / resolution).astype(np.int64) - n_pad, 0
        )
        i1 = np.minimum(
            np.ceil((np.asarray(hi) - full_lo) / resolution).astype(np.int64) + n_pad + 1, shape
        )
        i1 = np.maximum(i1, i0 + 1)
        cells = _cells_within(ij, i0, i1)
        r = math.floor(pad / resolution)
        # the values a distance transform gives at r^2 = 0 .. r*r cells squared, and beyond
        dist_of = np.minimum(np.sqrt(np.arange(r * r + 2, dtype=np.float64)) * resolution, cap)
        dist_of = dist_of.astype(np.float32)
        dist_of[-1] = cap
        like_of = np.exp(-(dist_of.astype(np.float64) ** 2) / (2 * sigma * sigma))
        like_of = like_of.astype(np.float32)
        like_of[-1] = 0.0
        sub = i1 - i0
        dist, like_t = _disc_field(cells, int(sub[1]), int(sub[0]), r, dist_of, like_of)
        origin = full_lo + i0 * resolution
        return cls(origin, resolution, like_t.T, like_t, dist)

    @classmethod
    def from_distance(
        cls,
        distance: np.ndarray,
        origin: np.ndarray,
        resolution: float,
        sigma: float,
        cap: float,
        box: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> LikelihoodGrid:
        """The grid of a distance field already at hand (H x W, row = y, capped at `cap`: a
        scan-to-map matcher's); cells at the cap (beyond the field's reach) have likelihood 0.
        No distance transform: one pass over the cells. With `box` (lo, hi: world x, y) the
        likelihood is computed only over the cells of the box (and 2 more around it), 0
        elsewhere: the fine level of a correlative search reads only where its points land
        (`correlative_search` asks for that box), and the whole field was most of its time;
        the cells it reads are the same, to the bit."""
        d = np.asarray(distance, dtype=np.float32)
        h, w = d.shape
        i0, j0, i1, j1 = 0, 0, w, h
        if box is not None:
            lo = np.floor((np.asarray(box[0]) - origin) / resolution).astype(np.int64) - 2
            hi = np.ceil((np.asarray(box[1]) - origin) / resolution).astype(np.int64) + 3
            i0, j0 = int(min(max(lo[0], 0), w)), int(min(max(lo[1], 0), h))
            i1, j1 = int(min(max(hi[0], i0), w)), int(min(max(hi[1], j0), h))
        like_t = _likelihood_t(d, sigma, cap, i0, i1, j0, j1)
        return cls(np.asarray(origin, dtype=np.float64), resolution, like_t.T, like_t, d)

    @classmethod
    def pooled(
        cls,
        distance: np.ndarray,
        origin: np.ndarray,
        resolution: float,
        pool: int,
        sigma: float,
        cap: float = 2.0,
    ) -> LikelihoodGrid:
        """A coarse grid (`pool` x `pool` cells of a distance field at hand to one) as `build`
        makes it: a coarse cell a surface passes through (a cell of it within `resolution` of
        one) is occupied, the rest get their distance to the nearest occupied one (a distance
        transform of the coarse cells only)."""
        occupied = _pool_min(np.asarray(distance, dtype=np.float32), pool) <= resolution
        step = resolution * pool
        distance_transform_edt = _edt()
        dist = np.minimum(distance_transform_edt(~occupied) * step, cap).astype(np.float32)
        like = np.exp(-(dist.astype(np.float64) ** 2) / (2 * sigma * sigma)).astype(np.float32)
        return cls(
            np.asarray(origin, dtype=np.float64), step, like, np.ascontiguousarray(like.T), dist
        )

    def score(self, points: np.ndarray, pose: np.ndarray) -> float:
        """Mean likelihood of `points` (N x 2, query frame) placed at `pose` in the grid frame."""
        return float(_score(self.likelihood, self.origin, self.resolution, points, pose))

    def distances(self, points: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """Distance (m) of each of `points` placed at `pose` to the nearest map point (the cap
        outside the grid)."""
        c, s = math.cos(pose[2]), math.sin(pose[2])
        pts = np.ascontiguousarray(points, dtype=np.float64)
        out = np.empty(len(pts))
        origin = np.asarray(self.origin, dtype=np.float64)
        outside = _lookup(self.distance, origin, self.resolution, pts, pose[0], pose[1], c, s, out)
        if outside.any():  # the grid's largest distance (a pass over every cell) only if needed
            out[outside] = float(self.distance.max())
        return out


@nb.njit(cache=True, nogil=True)
def _lookup(
    dist: np.ndarray,
    origin: np.ndarray,
    res: float,
    pts: np.ndarray,
    x0: float,
    y0: float,
    c: float,
    s: float,
    out: np.ndarray,
) -> np.ndarray:
    """`LikelihoodGrid.distances`' lookups (numpy's arithmetic, in one pass) into `out`;
    returns which points fall off the grid (their `out` is left to the caller)."""
    h, w = dist.shape
    outside = np.zeros(pts.shape[0], dtype=np.bool_)
    for k in range(pts.shape[0]):
        x = x0 + c * pts[k, 0] - s * pts[k, 1]
        y = y0 + s * pts[k, 0] + c * pts[k, 1]
        i = math.floor((x - origin[0]) / res)
        j = math.floor((y - origin[1]) / res)
        if 0 <= i < w and 0 <= j < h:
            out[k] = dist[j, i]
        else:
            outside[k] = True
    return outside


@nb.njit(cache=True, nogil=True)
def _placed_bounds(
    pts: np.ndarray, x0: float, y0: float, c: float, s: float, out: np.ndarray
) -> None:
    """The bounding box (x, y least, then largest) of `pts` turned by (c, s) and moved by
    (x0, y0), with numpy's arithmetic, into `out`."""
    for k in range(pts.shape[0]):
        x = x0 + c * pts[k, 0] - s * pts[k, 1]
        y = y0 + s * pts[k, 0] + c * pts[k, 1]
        if k == 0 or x < out[0]:
            out[0] = x
        if k == 0 or y < out[1]:
            out[1] = y
        if k == 0 or x > out[2]:
            out[2] = x
        if k == 0 or y > out[3]:
            out[3] = y


def _raster(
    points: np.ndarray, resolution: float, margin: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frame a grid of `points` (N x 2) has with `margin` m around their bounding box: its
    lower-left corner, its shape (columns, rows) and each point's cell (column, row); no
    points: a grid around the origin."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        pts = np.zeros((1, 2))
    lo = np.empty(2)
    shape = np.empty(2, dtype=np.int64)
    ij = np.empty((len(pts), 2), dtype=np.int64)
    _raster_cells(pts, resolution, margin, lo, shape, ij)
    return lo, shape, ij


@nb.njit(cache=True, nogil=True)
def _cells_within(ij: np.ndarray, i0: np.ndarray, i1: np.ndarray) -> np.ndarray:
    """The cells `ij` (N x 2) with i0 <= cell < i1 in both columns, moved by -i0, in their
    order: `ij[((ij >= i0) & (ij < i1)).all(axis=1)] - i0` in one pass (numpy's broadcast
    compares cost 0.1 ms over a reference map's few thousand points, at every search)."""
    out = np.empty_like(ij)
    m = 0
    for k in range(ij.shape[0]):
        i, j = ij[k, 0], ij[k, 1]
        if i0[0] <= i < i1[0] and i0[1] <= j < i1[1]:
            out[m, 0] = i - i0[0]
            out[m, 1] = j - i0[1]
            m += 1
    return out[:m].copy()


@nb.njit(cache=True, nogil=True)
def _inside(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """`points[((points >= lo) & (points <= hi)).all(axis=1)]` (N x 2 float64, the box's
    edges included) in one pass: the same rows in their order (a copy)."""
    out = np.empty_like(points)
    m = 0
    for k in range(points.shape[0]):
        x, y = points[k, 0], points[k, 1]
        if lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1]:
            out[m, 0] = x
            out[m, 1] = y
            m += 1
    return out[:m].copy()


def inside(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The rows of `points` (N x 2) within the box `lo`-`hi` (edges included), in order."""
    return _inside(
        np.ascontiguousarray(points, dtype=np.float64),
        np.asarray(lo, dtype=np.float64),
        np.asarray(hi, dtype=np.float64),
    )


def bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least and the largest x, y of `points` (N x 2, N > 0): `points.min(axis=0)` and
    `.max(axis=0)` in one pass (numpy's column reductions of an N x 2 array were a twentieth
    of a map run, in thousands of calls)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    lo, hi = np.empty(2), np.empty(2)
    _bounds(pts, lo, hi)
    return lo, hi


@nb.njit(cache=True, nogil=True)
def _bounds(pts: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
    """`bounds` into `lo`, `hi`."""
    lo[:] = pts[0]
    hi[:] = pts[0]
    for k in range(1, pts.shape[0]):
        for c in range(2):
            v = pts[k, c]
            if v < lo[c]:
                lo[c] = v
            if v > hi[c]:
                hi[c] = v


@nb.njit(cache=True, nogil=True)
def _raster_cells(
    pts: np.ndarray,
    resolution: float,
    margin: float,
    lo: np.ndarray,
    shape: np.ndarray,
    ij: np.ndarray,
) -> None:
    """`_raster`'s frame and cells into `lo`, `shape`, `ij`, with numpy's arithmetic."""
    hi = np.empty(2)
    _bounds(pts, lo, hi)
    for c in range(2):
        lo[c] -= margin
        shape[c] = math.ceil((hi[c] + margin - lo[c]) / resolution) + 1
    for k in range(pts.shape[0]):
        for c in range(2):
            ij[k, c] = math.floor((pts[k, c] - lo[c]) / resolution)


def _disc_field(
    cells: np.ndarray, h: int, w: int, r: int, dist_of: np.ndarray, like_of: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Distance (H x W) and likelihood transposed (W x H) of the occupied `cells` (N x 2:
    column, row) within `r` cells, from the tables `dist_of` / `like_of` indexed by the squared
    cell distance (their last entry: beyond `r`).

    An occupied cell stamps its disc only where no occupied neighbour is nearer: a cell p
    with (p - c) . e >= 1 for a side neighbour c + e (>= 2 for a diagonal one) is strictly
    nearer that neighbour, so the nearest occupied cell of every p still stamps it and the
    result is the same minimum; along a wall a cell stamps a line, not a disc. The squared
    distances are kept in bytes when they fit (r <= 15: the grids' radii, 10 and 15), which
    with a branch-free minimum lets the stamping vectorise (-22% of the call, session 30)."""
    far = r * r + 1
    d2 = np.full((h, w), far, dtype=np.uint8 if far <= 255 else np.int32)
    return _disc_stamp(cells, d2, r, dist_of, like_of)


@nb.njit(cache=True, nogil=True)
def _disc_stamp(
    cells: np.ndarray, d2: np.ndarray, r: int, dist_of: np.ndarray, like_of: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`_disc_field` into `d2` (H x W, every cell r * r + 1: beyond the disc)."""
    h, w = d2.shape
    far = r * r + 1
    occ = np.zeros((h + 2, w + 2), dtype=np.bool_)  # one cell of border, never occupied
    for k in range(cells.shape[0]):
        occ[cells[k, 1] + 1, cells[k, 0] + 1] = True
    half_w = np.empty(r + 1, dtype=np.int64)  # the disc's half width on a row dj away
    for dj in range(r + 1):
        m = r
        while m * m + dj * dj > r * r:
            m -= 1
        half_w[dj] = m
    for k in range(cells.shape[0]):
        ci, cj = cells[k, 0], cells[k, 1]
        if d2[cj, ci] == 0:
            continue
        d2[cj, ci] = 0
        # the clipping half-planes: dx <= bx_hi, dx >= bx_lo, dy likewise (side neighbours),
        # and +-dx +-dy <= 1 (diagonal ones)
        east, west = occ[cj + 1, ci + 2], occ[cj + 1, ci]
        north, south = occ[cj + 2, ci + 1], occ[cj, ci + 1]
        ne, nw = occ[cj + 2, ci + 2], occ[cj + 2, ci]
        se, sw = occ[cj, ci + 2], occ[cj, ci]
        dy0 = 0 if south else -r
        dy1 = 0 if north else r
        for dj in range(dy0, dy1 + 1):
            j = cj + dj
            if j < 0 or j >= h:
                continue
            m = half_w[abs(dj)]
            lo, hi = -m, m
            if east:
                hi = min(hi, 0)
            if west:
                lo = max(lo, 0)
            if ne:  # dx + dy <= 1
                hi = min(hi, 1 - dj)
            if se:  # dx - dy <= 1
                hi = min(hi, 1 + dj)
            if nw:  # -dx + dy <= 1
                lo = max(lo, dj - 1)
            if sw:  # -dx - dy <= 1
                lo = max(lo, -dj - 1)
            row = d2[j]
            dd = dj * dj
            for i in range(max(ci + lo, 0), min(ci + hi + 1, w)):
                d = np.int32((i - ci) * (i - ci) + dd)  # <= r * r: fits d2's type
                now = np.int32(row[i])
                row[i] = d if d < now else now
    # cells beyond r keep the tables' last entry: only those within it are written (the
    # transposed writes of every cell cost more than the stamping)
    dist = np.full((h, w), dist_of[far], dtype=np.float32)
    like_t = np.full((w, h), like_of[far], dtype=np.float32)
    for j in range(h):
        for i in range(w):
            d = d2[j, i]
            if d < far:
                dist[j, i] = dist_of[d]
                like_t[i, j] = like_of[d]
    return dist, like_t


@nb.njit(cache=True, nogil=True)
def _pool_min(dist: np.ndarray, pool: int) -> np.ndarray:
    """The least of each `pool` x `pool` block of `dist` (partial blocks at the edge left out)."""
    h, w = dist.shape[0] // pool, dist.shape[1] // pool
    out = np.full((h, w), np.inf, dtype=np.float32)
    for j in range(h * pool):
        for i in range(w * pool):
            d = dist[j, i]
            if d < out[j // pool, i // pool]:
                out[j // pool, i // pool] = d
    return out


@nb.njit(cache=True, nogil=True)
def _likelihood_t(
    dist: np.ndarray, sigma: float, cap: float, i0: int, i1: int, j0: int, j1: int
) -> np.ndarray:
    """exp(-d^2 / 2 sigma^2) of the distances `dist` (H x W), 0 at `cap`, transposed (W x H):
    over columns i0..i1 and rows j0..j1 (0 elsewhere). Read row by row, written only where
    a surface is within the cap (the rest of a map is the cap: zeros already), as the
    transposed writes of every cell cost more than the exponentials."""
    h, w = dist.shape
    out = np.zeros((w, h), dtype=np.float32)
    k = -0.5 / (sigma * sigma)
    for j in range(j0, j1):
        row = dist[j]
        for i in range(i0, i1):
            d = row[i]
            if d < cap:
                out[i, j] = math.exp(k * d * d)
    return out


@nb.njit(cache=True, nogil=True)
def _score(
    like: np.ndarray, origin: np.ndarray, res: float, pts: np.ndarray, pose: np.ndarray
) -> float:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    h, w = like.shape
    total = 0.0
    for k in range(pts.shape[0]):
        x = pose[0] + c * pts[k, 0] - s * pts[k, 1]
        y = pose[1] + s * pts[k, 0] + c * pts[k, 1]
        i = math.floor((x - origin[0]) / res)
        j = math.floor((y - origin[1]) / res)
        if 0 <= i < w and 0 <= j < h:
            total += like[j, i]
    return float(total / max(pts.shape[0], 1))


@nb.njit(cache=True, nogil=True)
def _search(
    like_t: np.ndarray,
    origin: np.ndarray,
    res: float,
    pts: np.ndarray,
    centre: np.ndarray,
    thetas: np.ndarray,
    half: int,
) -> np.ndarray:
    """Mean likelihood of `pts` at every pose centre + (i*res, j*res, theta) for i, j in
    [-half, half]: an array n_theta x (2 half + 1) x (2 half + 1) (theta, x, y). `like_t` is
    the grid transposed (x, y), so that the y offsets of one point read one contiguous run."""
    n = 2 * half + 1
    out = np.zeros((thetas.shape[0], n, n))
    w, h = like_t.shape
    npts = pts.shape[0]
    inv = 1.0 / res
    for a in range(thetas.shape[0]):
        th = centre[2] + thetas[a]
        c, s = math.cos(th), math.sin(th)
        acc = np.zeros((n, n))
        for k in range(npts):
            ci0 = math.floor((centre[0] + c * pts[k, 0] - s * pts[k, 1] - origin[0]) * inv)
            cj0 = math.floor((centre[1] + s * pts[k, 0] + c * pts[k, 1] - origin[1]) * inv)
            x0, y0 = ci0 - half, cj0 - half  # the cell of offset (0, 0)
            ilo, ihi = max(0, -x0), min(n, w - x0)
            jlo, jhi = max(0, -y0), min(n, h - y0)
            if jlo == 0 and jhi == n:
                # every y offset on the grid (most points): a run of n from 0, which the
                # compiler vectorises (twice the speed of the clipped loop below)
                for i in range(ilo, ihi):
                    row = like_t[x0 + i, y0 : y0 + n]
                    ai = acc[i]
                    for j in range(n):
                        ai[j] += row[j]
            else:
                for i in range(ilo, ihi):
                    row = like_t[x0 + i]
                    ai = acc[i]
                    for j in range(jlo, jhi):
                        ai[j] += row[y0 + j]
        out[a] = acc / max(npts, 1)
    return out


# ------------------------------------------------------- branch and bound (the coarse level)

_WORK_LIMIT = 0.5  # share of the exhaustive search's lookups after which bounding gives up


@nb.njit(cache=True, nogil=True)
def _cells_of(
    origin: np.ndarray, res: float, pts: np.ndarray, centre: np.ndarray, thetas: np.ndarray
) -> np.ndarray:
    """Each point's cell (column, row) at every heading, the offsets (0, 0): A x N x 2, with
    `_search`'s arithmetic (so that the scores are its own, to the bit)."""
    out = np.empty((thetas.shape[0], pts.shape[0], 2), dtype=np.int64)
    inv = 1.0 / res
    for a in range(thetas.shape[0]):
        th = centre[2] + thetas[a]
        c, s = math.cos(th), math.sin(th)
        for k in range(pts.shape[0]):
            out[a, k, 0] = math.floor((centre[0] + c * pts[k, 0] - s * pts[k, 1] - origin[0]) * inv)
            out[a, k, 1] = math.floor((centre[1] + s * pts[k, 0] + c * pts[k, 1] - origin[1]) * inv)
    return out


@nb.njit(cache=True, nogil=True)
def _pyramid(like_t: np.ndarray, levels: int) -> np.ndarray:
    """Max-pooled grids: level L, cell (x + P, y + P), P = 2^(levels - 1), holds the largest
    likelihood of the 2^L x 2^L cells from (x, y) up (0 off the grid): an upper bound of the
    likelihood anywhere a point lands when its offset moves within a block of 2^L x 2^L.

    Only the cells whose block meets the grid are computed (x + P from P - 2^L + 1 up to
    P + W, likewise y): the rest are 0 as allocated, which is what the max of their
    off-grid cells gives. A max is exact, so the values are the full computation's to the
    bit; the padding of a wide window's top levels was most of the work."""
    w, h = like_t.shape
    p = 1 << (levels - 1)
    big_w, big_h = w + 2 * p, h + 2 * p
    out = np.zeros((levels, big_w, big_h), dtype=np.float32)
    for x in range(w):
        out[0, x + p, p : p + h] = like_t[x]
    for lv in range(1, levels):
        s = 1 << (lv - 1)
        lo = p - (1 << lv) + 1  # >= 1: the first cell whose block meets the grid
        prev = out[lv - 1]
        cur = out[lv]
        # x + s < big_w and y + s < big_h over these cells (s < p): no bounds test
        for x in range(lo, p + w):
            a, b, c = prev[x], prev[x + s], cur[x]
            for y in range(lo, p + h):
                c[y] = max(max(a[y], b[y]), max(a[y + s], b[y + s]))
    return out


@nb.njit(cache=True, nogil=True, inline="always")
def _sum_at(grid: np.ndarray, cells: np.ndarray, a: int, dx: int, dy: int, pad: int) -> float:
    """Sum over the points of grid[cell + (dx, dy) + pad] (0 off the grid), in point order."""
    w, h = grid.shape
    total = 0.0
    for k in range(cells.shape[1]):
        x = cells[a, k, 0] + dx + pad
        y = cells[a, k, 1] + dy + pad
        if 0 <= x < w and 0 <= y < h:
            total += grid[x, y]
    return total


@nb.njit(cache=True, nogil=True, inline="always")
def _sum_quad(
    grid: np.ndarray,
    cells: np.ndarray,
    box: np.ndarray,
    a: int,
    dx: int,
    dy: int,
    s: int,
    pad: int,
    out: np.ndarray,
) -> None:
    """`_sum_at` at the four offsets (dx, dy) + (0 or s, 0 or s) in one pass over the points
    (out[2 i + j]: + (i s, j s)), each sum in point order as `_sum_at`'s: a block's four
    children read neighbouring cells, so one pass reads each point's cache lines once. When
    the points' cells at heading `a` (their bounding box `box[a]`: x least, largest, y least,
    largest) land on the grid at all four offsets, as nearly always, without a test per
    point (the same sums)."""
    w, h = grid.shape
    t00 = t01 = t10 = t11 = 0.0
    if (
        box[a, 0] + dx + pad >= 0
        and box[a, 1] + dx + s + pad < w
        and box[a, 2] + dy + pad >= 0
        and box[a, 3] + dy + s + pad < h
    ):
        for k in range(cells.shape[1]):
            x = cells[a, k, 0] + dx + pad
            y = cells[a, k, 1] + dy + pad
            t00 += grid[x, y]
            t01 += grid[x, y + s]
            t10 += grid[x + s, y]
            t11 += grid[x + s, y + s]
        out[0], out[1], out[2], out[3] = t00, t01, t10, t11
        return
    for k in range(cells.shape[1]):
        x = cells[a, k, 0] + dx + pad
        y = cells[a, k, 1] + dy + pad
        x_in, x2_in = 0 <= x < w, 0 <= x + s < w
        y_in, y2_in = 0 <= y < h, 0 <= y + s < h
        if x_in:
            if y_in:
                t00 += grid[x, y]
            if y2_in:
                t01 += grid[x, y + s]
        if x2_in:
            if y_in:
                t10 += grid[x + s, y]
            if y2_in:
                t11 += grid[x + s, y + s]
    out[0], out[1], out[2], out[3] = t00, t01, t10, t11


@nb.njit(cache=True, nogil=True, inline="always")
def _swap(heap: np.ndarray, key: np.ndarray, a: int, b: int) -> None:
    """Swap entries `a` and `b` of the heap (their keys and rows)."""
    key[a], key[b] = key[b], key[a]
    for c in range(heap.shape[1]):
        heap[a, c], heap[b, c] = heap[b, c], heap[a, c]


@nb.njit(cache=True, nogil=True, inline="always")
def _push(heap: np.ndarray, key: np.ndarray, state: np.ndarray, k: float, row: np.ndarray) -> None:
    """Push (k, row) on the max-heap `key` / `heap` (rows: heading, level, x, y)."""
    m = state[0]
    key[m] = k
    heap[m] = row
    while m > 0:
        up = (m - 1) // 2
        if key[up] >= key[m]:
            break
        _swap(heap, key, up, m)
        m = up
    state[0] += 1


@nb.njit(cache=True, nogil=True, inline="always")
def _pop(heap: np.ndarray, key: np.ndarray, state: np.ndarray, row: np.ndarray) -> float:
    """Pop the largest key of the heap into `row`; return it."""
    top: float = key[0]
    row[:] = heap[0]
    m = state[0] - 1
    state[0] = m
    key[0] = key[m]
    heap[0] = heap[m]
    k = 0
    while True:
        c = 2 * k + 1
        if c >= m:
            break
        if c + 1 < m and key[c + 1] > key[c]:
            c += 1
        if key[k] >= key[c]:
            break
        _swap(heap, key, k, c)
        k = c
    return top


@nb.njit(cache=True, nogil=True)
def _bnb_start(
    pyramid: np.ndarray,
    cells: np.ndarray,
    half: int,
    heap: np.ndarray,
    key: np.ndarray,
    state: np.ndarray,
) -> None:
    """The roots: one block of 2^L x 2^L offsets per heading, bounded by the top level."""
    levels = pyramid.shape[0]
    pad = 1 << (levels - 1)
    div = max(cells.shape[1], 1)
    row = np.zeros(4, dtype=np.int64)
    for a in range(cells.shape[0]):
        row[0], row[1] = a, levels - 1
        _push(
            heap, key, state, _sum_at(pyramid[levels - 1], cells, a, -half, -half, pad) / div, row
        )
        state[1] += cells.shape[1]


@nb.njit(cache=True, nogil=True)
def _bnb_next(
    like_t: np.ndarray,
    pyramid: np.ndarray,
    cells: np.ndarray,
    half: int,
    heap: np.ndarray,
    key: np.ndarray,
    state: np.ndarray,
    seen: np.ndarray,
    seen_key: np.ndarray,
    box: np.ndarray,
) -> bool:
    """Expand the heap's best blocks until its best entry is one offset (scored: its key is
    `_search`'s score); move it to `seen`. Offsets so come out best first: a block's key
    bounds each of its offsets' scores (a leaf is `_search`'s sum in its order, the bound
    the same sum over the pyramid's larger values, and rounding is monotone). False when the
    heap is empty. state: heap size, lookups made, offsets seen."""
    n = 2 * half + 1
    npts = cells.shape[1]
    div = max(npts, 1)
    pad = 1 << (pyramid.shape[0] - 1)
    row = np.zeros(4, dtype=np.int64)
    child = np.zeros(4, dtype=np.int64)
    sums = np.zeros(4)
    while state[0] > 0:
        k = _pop(heap, key, state, row)
        a, lv, x0, y0 = row[0], row[1], row[2], row[3]
        if lv < 0:  # an offset, scored
            m = state[2]
            seen[m] = row
            seen_key[m] = k
            state[2] = m + 1
            return True
        if lv == 0:  # the whole window is one offset: score it
            child[0], child[1], child[2], child[3] = a, -1, x0, y0
            _push(heap, key, state, _sum_at(like_t, cells, a, x0 - half, y0 - half, 0) / div, child)
            state[1] += npts
            continue
        s = 1 << (lv - 1)
        if lv == 1:
            _sum_quad(like_t, cells, box, a, x0 - half, y0 - half, s, 0, sums)
        else:
            _sum_quad(pyramid[lv - 1], cells, box, a, x0 - half, y0 - half, s, pad, sums)
        for dx in range(2):
            for dy in range(2):
                xx, yy = x0 + dx * s, y0 + dy * s
                if xx >= n or yy >= n:
                    continue
                child[0], child[1], child[2], child[3] = a, lv - 1 if lv > 1 else -1, xx, yy
                state[1] += npts
                _push(heap, key, state, sums[2 * dx + dy] / div, child)
    return False


@dataclass(frozen=True)
class SearchResult:
    """The best pose of a correlative search and how clearly it won."""

    pose: np.ndarray  # (3,) query frame in the grid frame
    score: float  # mean likelihood at the fine level
    coarse_score: float  # the winner's coarse score
    runner_up: float  # best coarse score away from the winner (another mode)
    inliers: float  # share of query points within `inlier_distance` of a map point

    @property
    def ambiguity(self) -> float:
        """The runner-up's coarse score over the winner's: near 1, another mode as good."""
        return self.runner_up / max(self.coarse_score, 1e-9)


@nb.njit(cache=True, nogil=True)
def _within(offsets: np.ndarray, i: int, j: int, reach: float) -> np.ndarray:
    """The coarse offsets (x, y indices) within `reach` m of offset (i, j)."""
    n = offsets.shape[0]
    out = np.empty((n, n), dtype=np.bool_)
    for ii in range(n):
        dx = offsets[ii] - offsets[i]
        for jj in range(n):
            out[ii, jj] = math.hypot(dx, offsets[jj] - offsets[j]) <= reach
    return out


@nb.njit(cache=True, nogil=True)
def _within_near(
    offsets: np.ndarray, i: int, j: int, reach: float, step: float
) -> tuple[np.ndarray, int, int, int, int]:
    """`_within(offsets, i, j, reach)` (the same booleans) with the offsets `step` apart
    (`_lattice`'s), each computed only in the box of offsets within `reach` / `step` + 2
    indices of (i, j), and that box (ii from i0 to i1, jj from j0 to j1, ends excluded):
    outside it an offset is more than a whole step beyond `reach`, so no rounding of the
    hypot makes it within, and the rest of the array is False."""
    n = offsets.shape[0]
    out = np.zeros((n, n), dtype=np.bool_)
    r = int(reach / step) + 2
    i0, i1 = max(i - r, 0), min(i + r + 1, n)
    j0, j1 = max(j - r, 0), min(j + r + 1, n)
    for ii in range(i0, i1):
        dx = offsets[ii] - offsets[i]
        for jj in range(j0, j1):
            out[ii, jj] = math.hypot(dx, offsets[jj] - offsets[j]) <= reach
    return out, i0, i1, j0, j1


def _starts(
    vol: np.ndarray,
    offsets: np.ndarray,
    thetas: np.ndarray,
    step: float,
    turn_step: float,
    count: int,
) -> list[tuple[int, int, int]] | None:
    """The fine search's starts (heading, x, y indices into `vol`), best first, each the best pose not
    next to one picked before (within 1.5 steps and 1.5 heading steps): what a walk down the
    sorted scores picks, without sorting them all (a full sort was a quarter of a search's
    time). None when a pick has equal scores elsewhere: a sort's order of equal scores is
    its own, so the caller walks the sorted scores then (`_starts_sorted`), and the result
    is the same either way."""
    tops: list[tuple[int, int, int]] = []
    free = np.ones(vol.shape, dtype=bool)
    for _ in range(min(count, vol.size)):
        masked = np.where(free, vol, -np.inf).ravel()
        k = int(np.argmax(masked))
        if not np.isfinite(masked[k]):
            break
        if np.count_nonzero(masked == masked[k]) > 1:
            return None
        a, i, j = (int(x) for x in np.unravel_index(k, vol.shape))
        p = np.array([offsets[i], offsets[j], thetas[a]])
        tops.append((a, i, j))
        near_xy = _within(offsets, i, j, 1.5 * step)
        near_t = np.abs(thetas - p[2]) <= 1.5 * turn_step
        free &= ~(near_t[:, None, None] & near_xy[None])
    return tops


def _starts_sorted(
    vol: np.ndarray,
    offsets: np.ndarray,
    thetas: np.ndarray,
    step: float,
    turn_step: float,
    count: int,
) -> list[tuple[int, int, int]]:
    """`_starts` by a walk down the sorted scores (equal scores in the sort's order)."""
    flat = np.argsort(vol.ravel())[::-1]
    a, i, j = np.unravel_index(flat, vol.shape)
    tops: list[tuple[int, int, int]] = []
    picked: list[np.ndarray] = []
    for k in range(len(flat)):
        p = np.array([offsets[i[k]], offsets[j[k]], thetas[a[k]]])
        if all(
            np.hypot(*(p[:2] - q[:2])) > 1.5 * step or abs(p[2] - q[2]) > 1.5 * turn_step
            for q in picked
        ):
            picked.append(p)
            tops.append((int(a[k]), int(i[k]), int(j[k])))
        if len(tops) >= count:
            break
    return tops


def _far(
    offsets: np.ndarray,
    thetas: np.ndarray,
    a: int,
    i: int,
    j: int,
    away: float,
    away_turn: float,
) -> np.ndarray:
    """The coarse poses (heading, x, y) at least `away` m or `away_turn` rad from pose
    (a, i, j): where the runner-up is looked for."""
    d_theta = np.abs(thetas - thetas[a])[:, None, None]
    out: np.ndarray = ~_within(offsets, i, j, away)[None] | (d_theta > away_turn)
    return np.ascontiguousarray(np.broadcast_to(out, (len(thetas), len(offsets), len(offsets))))


def _bounded_starts(
    coarse: LikelihoodGrid,
    pts: np.ndarray,
    prediction: np.ndarray,
    thetas: np.ndarray,
    half: int,
    offsets: np.ndarray,
    turn_step: float,
    count: int,
    away: float,
    away_turn: float,
) -> tuple[list[tuple[int, int, int]], float, float] | None:
    """What the exhaustive coarse level gives (`_starts`' picks, the winner's score, the
    runner-up), by branch and bound: the coarse poses come out best first (`_bnb_next`), the
    picks are the first not next to one picked before, the runner-up the first far from the
    winner; only blocks that could hold a better pose than those are ever scored. None when a
    pick has an equal score elsewhere (the sorted walk's order then needs the whole volume)
    or when bounding prunes too little (more than `_WORK_LIMIT` of the exhaustive lookups).
    The walk is one numba call (`_bnb_picks`)."""
    step = coarse.resolution
    n = 2 * half + 1
    n_a = len(thetas)
    levels = max(math.ceil(math.log2(n)), 0) + 1
    cells = _cells_of(coarse.origin, step, pts, prediction, thetas)
    pyramid = _pyramid(coarse.likelihood_t, levels)
    budget = _WORK_LIMIT * n_a * n * n * max(len(pts), 1)
    size = n_a * (2 * n * n + 8 * levels * n + 8)  # every block and offset, once
    tops = np.zeros((max(min(count, n_a * n * n), 1), 3), dtype=np.int64)
    picks, best, runner_up = _bnb_picks(
        coarse.likelihood_t, pyramid, cells, half, offsets, thetas, step, turn_step, away,
        away_turn, budget, size, tops,
    )  # fmt: skip
    if picks <= 0:
        return None
    return [(int(a), int(i), int(j)) for a, i, j in tops[:picks]], best, runner_up


@nb.njit(cache=True, nogil=True)
def _cell_box(cells: np.ndarray) -> np.ndarray:
    """Per heading, the bounding box of the points' cells (A x N x 2): A x 4, x least, x
    largest, y least, y largest (`_sum_quad`'s test that every point lands on the grid)."""
    out = np.zeros((cells.shape[0], 4), dtype=np.int64)
    if cells.shape[1] == 0:
        return out
    for a in range(cells.shape[0]):
        out[a, 0] = out[a, 1] = cells[a, 0, 0]
        out[a, 2] = out[a, 3] = cells[a, 0, 1]
        for k in range(1, cells.shape[1]):
            out[a, 0] = min(out[a, 0], cells[a, k, 0])
            out[a, 1] = max(out[a, 1], cells[a, k, 0])
            out[a, 2] = min(out[a, 2], cells[a, k, 1])
            out[a, 3] = max(out[a, 3], cells[a, k, 1])
    return out


@nb.njit(cache=True, nogil=True)
def _bnb_after(k: int, budget: float, bnb: tuple) -> bool:  # type: ignore[type-arg]
    """Offset number k has come out of the branch and bound `bnb` (`_bnb_next`'s arguments)
    (False: none left, or the lookups are over `budget`)."""
    state = bnb[6]
    while state[2] <= k:
        if state[1] > budget or not _bnb_next(*bnb):
            return False
    return True


@nb.njit(cache=True, nogil=True)
def _bnb_picks(
    like_t: np.ndarray,
    pyramid: np.ndarray,
    cells: np.ndarray,
    half: int,
    offsets: np.ndarray,
    thetas: np.ndarray,
    step: float,
    turn_step: float,
    away: float,
    away_turn: float,
    budget: float,
    size: int,
    tops: np.ndarray,
) -> tuple[int, float, float]:
    """`_bounded_starts`' walk: the picks (heading, x, y) into `tops` (as many as it has rows),
    each the best offset not next to one picked before (within 1.5 steps and 1.5 heading
    steps), then the runner-up (the best offset `away` m or `away_turn` rad from the winner,
    0 when there is none). Returns the number of picks (0: give up, the caller scores the
    whole volume), the winner's score and the runner-up's."""
    n = 2 * half + 1
    n_a = thetas.shape[0]
    heap = np.empty((size, 4), dtype=np.int64)
    key = np.empty(size)
    seen = np.empty((n_a * n * n, 4), dtype=np.int64)
    seen_key = np.empty(n_a * n * n)
    state = np.zeros(3, dtype=np.int64)
    _bnb_start(pyramid, cells, half, heap, key, state)
    box = _cell_box(cells)
    bnb = (like_t, pyramid, cells, half, heap, key, state, seen, seen_key, box)
    free = np.ones((n_a, n, n), dtype=np.bool_)
    near_t = 1.5 * turn_step
    picks = 0
    best = 0.0
    k = 0
    for _ in range(tops.shape[0]):
        while _bnb_after(k, budget, bnb):
            if free[seen[k, 0], seen[k, 2], seen[k, 3]]:
                break
            k += 1
        if state[2] <= k:  # none left (every pose is next to a pick) or over budget
            if state[1] > budget:
                return 0, 0.0, 0.0
            break
        a, i, j = seen[k, 0], seen[k, 2], seen[k, 3]
        score = seen_key[k]
        m = k + 1  # an equal score among the free poses: the sorted walk decides
        while _bnb_after(m, budget, bnb):
            if seen_key[m] != score:
                break
            if free[seen[m, 0], seen[m, 2], seen[m, 3]]:
                return 0, 0.0, 0.0
            m += 1
        if state[1] > budget:
            return 0, 0.0, 0.0
        tops[picks, 0], tops[picks, 1], tops[picks, 2] = a, i, j
        if picks == 0:
            best = score
        picks += 1
        near, i0, i1, j0, j1 = _within_near(offsets, i, j, 1.5 * step, step)
        for aa in range(n_a):
            if abs(thetas[aa] - thetas[a]) <= near_t:
                for ii in range(i0, i1):  # near is False outside its box
                    for jj in range(j0, j1):
                        if near[ii, jj]:
                            free[aa, ii, jj] = False
        k += 1
    if picks == 0:
        return 0, 0.0, 0.0
    a, i, j = tops[0, 0], tops[0, 1], tops[0, 2]
    far_xy = ~_within_near(offsets, i, j, away, step)[0]  # `_far`'s poses: far_xy or far_t
    far_t = np.empty(n_a, dtype=np.bool_)
    for aa in range(n_a):
        far_t[aa] = abs(thetas[aa] - thetas[a]) > away_turn
    any_far = far_xy.any() or far_t.any()
    runner_up = 0.0
    if any_far:
        k = 0
        while _bnb_after(k, budget, bnb):
            if far_t[seen[k, 0]] or far_xy[seen[k, 2], seen[k, 3]]:
                break
            k += 1
        if state[2] <= k:
            return 0, 0.0, 0.0  # over budget (a far pose exists)
        runner_up = seen_key[k]
    return picks, best, runner_up


def _lattice(
    step: float, window: float, turn: float, turn_step: float
) -> tuple[int, np.ndarray, np.ndarray]:
    """The coarse level's poses: half its cells across (+-`window` m in cells of `step`), its
    x = y offsets (m) and its headings (+-`turn` rad by `turn_step`)."""
    half = max(round(window / step), 0)
    offsets = (np.arange(2 * half + 1) - half) * step
    return half, offsets, np.arange(-turn, turn + 1e-9, turn_step)


def _coarse_level(
    coarse: LikelihoodGrid,
    pts: np.ndarray,
    prediction: np.ndarray,
    window: float,
    turn: float,
    turn_step: float,
    candidates: int,
    away: float,
    away_turn: float,
    exhaustive: bool = False,
) -> tuple[list[tuple[int, int, int]], float, float, np.ndarray, np.ndarray]:
    """The coarse level of `correlative_search`: the `candidates` starts (heading, x, y
    cells; the winner first), the winner's score, the runner-up's, the offsets and headings;
    by branch and bound, or from the whole volume when asked (`exhaustive`) or when bounding
    gives up."""
    half, offsets, thetas = _lattice(coarse.resolution, window, turn, turn_step)
    if not exhaustive:
        bounded = _bounded_starts(
            coarse, pts, prediction, thetas, half, offsets, turn_step, candidates, away,
            away_turn,
        )  # fmt: skip
        if bounded is not None:
            return (*bounded, offsets, thetas)
    vol = _search(
        coarse.likelihood_t, coarse.origin, coarse.resolution, pts, prediction, thetas, half
    )
    step = coarse.resolution
    picks = _starts(vol, offsets, thetas, step, turn_step, candidates)
    # equal scores among the picks (None): as the sorted walk orders them
    starts = (
        picks
        if picks is not None
        else _starts_sorted(vol, offsets, thetas, step, turn_step, candidates)
    )
    best_a, best_i, best_j = starts[0]  # the winner
    far = _far(offsets, thetas, best_a, best_i, best_j, away, away_turn)
    runner_up = float(vol[far].max()) if far.any() else 0.0
    return starts, float(vol[best_a, best_i, best_j]), runner_up, offsets, thetas


@functools.lru_cache(maxsize=8)
def _linspace7(turn_step: float) -> np.ndarray:
    """`np.linspace(-turn_step, turn_step, 7)`, made once per step (`_fine_thetas`)."""
    return np.linspace(-turn_step, turn_step, 7)


def _fine_thetas(turn_step: float) -> np.ndarray:
    """The fine level's 7 headings over +-`turn_step`: `np.linspace`'s, copied from a cache
    (a copy costs a third of making them, and the caller's array stays its own)."""
    return _linspace7(turn_step).copy()


def correlative_search(
    coarse: LikelihoodGrid,
    fine: LikelihoodGrid | Callable[[np.ndarray, np.ndarray], LikelihoodGrid],
    points: np.ndarray,
    prediction: np.ndarray,
    window: float,
    turn: float,
    turn_step: float,
    coarse_voxel: float = 0.0,
    away: float = 0.6,
    away_turn: float = 0.15,
    inlier_distance: float = 0.1,
    candidates: int = 3,
    fine_resolution: float = 0.0,
    exhaustive: bool = False,
) -> SearchResult:
    """Exhaustive coarse search of the window (+-`window` m, +-`turn` rad around
    `prediction`), then a fine search around the `candidates` best coarse poses. The runner-up
    is the best coarse score at least `away` m or `away_turn` rad from the winner: a
    repetitive place (a corridor) has one close to the winner's. `fine` may be a function of
    a box (lo, hi) that gives the fine grid over it (`LikelihoodGrid.window`): it is asked for
    the box where the points land in the fine search, once the coarse poses are known.

    The coarse level is searched by branch and bound (`_bounded_starts`: the same starts,
    winner's score and runner-up, to the bit, from a fraction of the lookups); `exhaustive`
    scores every coarse pose instead (what the bounding is checked against). The two levels
    are `coarse_search` and `fine_search` (a caller may stop after the first)."""
    level = coarse_search(
        coarse, points, prediction, window, turn, turn_step, coarse_voxel, away, away_turn,
        candidates, exhaustive,
    )  # fmt: skip
    return fine_search(level, fine, inlier_distance, fine_resolution)


@dataclass(frozen=True)
class CoarseLevel:
    """`correlative_search`'s coarse level: what its fine level starts from, and the winner's
    and runner-up's coarse scores (all the ambiguity test needs)."""

    coarse: LikelihoodGrid
    points: np.ndarray  # the query points (N x 2, float64, contiguous)
    prediction: np.ndarray
    turn_step: float
    starts: list[tuple[int, int, int]]  # (heading, x, y) cells, the winner first
    offsets: np.ndarray
    thetas: np.ndarray
    coarse_score: float
    runner_up: float

    @property
    def ambiguity(self) -> float:
        """`SearchResult.ambiguity` (the same formula on the same two scores)."""
        return self.runner_up / max(self.coarse_score, 1e-9)

    def winner(self) -> np.ndarray:
        """The coarse winner's pose (heading wrapped): where a search stopped here puts the
        query."""
        a, i, j = self.starts[0]
        pose: np.ndarray = self.prediction + np.array(
            [self.offsets[i], self.offsets[j], self.thetas[a]]
        )
        pose[2] = math.atan2(math.sin(pose[2]), math.cos(pose[2]))
        return pose


def coarse_search(
    coarse: LikelihoodGrid,
    points: np.ndarray,
    prediction: np.ndarray,
    window: float,
    turn: float,
    turn_step: float,
    coarse_voxel: float = 0.0,
    away: float = 0.6,
    away_turn: float = 0.15,
    candidates: int = 3,
    exhaustive: bool = False,
) -> CoarseLevel:
    """`correlative_search`'s coarse level alone (its arguments of the same names)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    coarse_pts = (
        np.ascontiguousarray(voxel_subsample(pts, coarse_voxel)) if coarse_voxel > 0 else pts
    )
    starts, coarse_score, runner_up, offsets, thetas = _coarse_level(
        coarse, coarse_pts, prediction, window, turn, turn_step, candidates, away, away_turn,
        exhaustive,
    )  # fmt: skip
    return CoarseLevel(
        coarse, pts, prediction, turn_step, starts, offsets, thetas, coarse_score, runner_up
    )


def fine_search(
    level: CoarseLevel,
    fine: LikelihoodGrid | Callable[[np.ndarray, np.ndarray], LikelihoodGrid],
    inlier_distance: float = 0.1,
    fine_resolution: float = 0.0,
) -> SearchResult:
    """`correlative_search`'s fine level from its coarse level `level`."""
    pts, prediction, turn_step = level.points, level.prediction, level.turn_step
    offsets, thetas = level.offsets, level.thetas
    coarse_step = level.coarse.resolution
    tops = [np.array([offsets[i], offsets[j], thetas[a]]) for a, i, j in level.starts]
    if callable(fine):
        fine_res = fine_resolution
        fine_half = math.ceil(coarse_step / fine_res)
        reach = (
            fine_half * fine_res + turn_step * float(np.hypot(pts[:, 0], pts[:, 1]).max()) + 0.05
        )
        box = np.empty((len(tops), 4))
        for m, p in enumerate(tops):
            th = prediction[2] + p[2]
            c, s = math.cos(th), math.sin(th)
            _placed_bounds(pts, prediction[0] + p[0], prediction[1] + p[1], c, s, box[m])
        fine = fine(box[:, :2].min(axis=0) - reach, box[:, 2:].max(axis=0) + reach)
    fine_step = fine.resolution
    fine_half = math.ceil(coarse_step / fine_step)
    fine_thetas = _fine_thetas(turn_step)
    best = (-1.0, prediction)
    for p in tops:
        centre = np.array([prediction[0] + p[0], prediction[1] + p[1], prediction[2] + p[2]])
        fv = _search(
            fine.likelihood_t, fine.origin, fine.resolution, pts, centre, fine_thetas, fine_half
        )
        fa, fi, fj = np.unravel_index(int(np.argmax(fv)), fv.shape)
        if fv[fa, fi, fj] > best[0]:
            pose = centre + np.array(
                [(fi - fine_half) * fine_step, (fj - fine_half) * fine_step, fine_thetas[fa]]
            )
            best = (float(fv[fa, fi, fj]), pose)
    pose = best[1].copy()
    pose[2] = math.atan2(math.sin(pose[2]), math.cos(pose[2]))
    inliers = float(np.mean(fine.distances(pts, pose) <= inlier_distance))
    return SearchResult(pose, best[0], level.coarse_score, level.runner_up, inliers)


def coarse_ambiguity(
    coarse: LikelihoodGrid,
    points: np.ndarray,
    prediction: np.ndarray,
    window: float,
    turn: float,
    turn_step: float,
    away: float = 0.6,
    away_turn: float = 0.15,
) -> tuple[float, float]:
    """The coarse level of `correlative_search` for `points` alone: its winner's score and
    the runner-up (the best at least `away` m or `away_turn` rad from the winner), by branch
    and bound, or from the whole volume when bounding gives up."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    _, best, runner_up, _, _ = _coarse_level(
        coarse, pts, prediction, window, turn, turn_step, 1, away, away_turn
    )
    return best, runner_up


def coarse_scores(
    coarse: LikelihoodGrid,
    points: np.ndarray,
    prediction: np.ndarray,
    window: float,
    turn: float,
    turn_step: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The coarse level of `correlative_search` scored whole: the volume (heading, x, y) of
    mean likelihoods at prediction + (x, y, theta), its x = y offsets and its headings (the
    shape of the score surface: which way a corridor's match is free)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    half, offsets, thetas = _lattice(coarse.resolution, window, turn, turn_step)
    vol = _search(
        coarse.likelihood_t, coarse.origin, coarse.resolution, pts, prediction, thetas, half
    )
    return vol, offsets, thetas


def voxel_subsample(points: np.ndarray, size: float) -> np.ndarray:
    """One point per `size` m cell (the first), in the points' order."""
    if len(points) == 0:
        return points
    keep = None
    if points.dtype == np.float64 and points.ndim == 2 and points.shape[1] == 2:
        keep = _first_in_cell(np.ascontiguousarray(points), size, _VOXEL_TABLE)
    if keep is None:  # cells too many for a table: sort their codes instead
        cells = np.floor(points / size).astype(np.int64)
        cells -= cells.min(axis=0)
        code = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]  # one int per cell
        _, first = np.unique(code, return_index=True)
        out: np.ndarray = points[np.sort(first)]
        return out
    kept: np.ndarray = points[keep]
    return kept


_VOXEL_TABLE = 1 << 22  # most cells of `voxel_subsample`'s bounding box for its table


@nb.njit(cache=True, nogil=True)
def _first_in_cell(pts: np.ndarray, size: float, most: int) -> np.ndarray | None:
    """Which of `pts` (N x 2) is the first in its `size` m cell: a table over the cells of
    their bounding box (None when it has more than `most` cells), in one pass, instead of
    a sort of the cells' codes (the same points: the first of each cell, in order)."""
    n = pts.shape[0]
    cells = np.empty((n, 2), dtype=np.int64)
    for k in range(n):
        cells[k, 0] = math.floor(pts[k, 0] / size)
        cells[k, 1] = math.floor(pts[k, 1] / size)
    lo0, lo1 = cells[0, 0], cells[0, 1]
    hi0, hi1 = lo0, lo1
    for k in range(1, n):
        lo0, hi0 = min(lo0, cells[k, 0]), max(hi0, cells[k, 0])
        lo1, hi1 = min(lo1, cells[k, 1]), max(hi1, cells[k, 1])
    rows = hi1 - lo1 + 1
    if (hi0 - lo0 + 1) * rows > most:
        return None
    seen = np.zeros((hi0 - lo0 + 1) * rows, dtype=np.bool_)
    keep = np.zeros(n, dtype=np.bool_)
    for k in range(n):
        c = (cells[k, 0] - lo0) * rows + cells[k, 1] - lo1
        if not seen[c]:
            seen[c] = True
            keep[k] = True
    return keep


_EPS = 1e-6  # slack (m) of the stamped regions' bounds: a cell on a bound is stamped


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _cut(
    lo: float, hi: float, nx: float, ny: float, vx: float, vy: float, y: float, c: float
) -> tuple[float, float]:
    """The interval [lo, hi] of x on the row at y, cut by nx (x - vx) + ny (y - vy) <= c."""
    r = c - ny * (y - vy)
    if nx > 0.0:
        hi = min(hi, vx + r / nx)
    elif nx < 0.0:
        lo = max(lo, vx + r / nx)
    elif r < 0.0:
        lo = math.inf
    return lo, hi


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _disc(vx: float, vy: float, y: float, cap: float) -> tuple[float, float]:
    """The interval of x on the row at y within `cap` of (vx, vy) (empty: inf, -inf)."""
    e = y - vy
    if abs(e) > cap:
        return math.inf, -math.inf
    r = math.sqrt(cap * cap - e * e)
    return vx - r, vx + r


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _cells(
    dist: np.ndarray,
    j: int,
    lo: float,
    hi: float,
    ox: float,
    cy: float,
    res: float,
    inv: float,
    ax: float,
    ay: float,
    dx: float,
    dy: float,
    ll: float,
) -> None:
    """Lower row `j` (centre height cy) of `dist` between x = lo and hi to the distance of
    each cell centre to the segment (ax, ay) + t (dx, dy), t in [0, 1]."""
    if lo > hi:
        return
    i0 = max(math.ceil((lo - ox) * inv - 0.5), 0)
    i1 = min(math.floor((hi - ox) * inv - 0.5) + 1, dist.shape[1])
    if i0 >= i1:
        return
    row = dist[j, i0:i1]
    ey0 = cy - ay
    if ll == 0.0:
        e2y = ey0 * ey0
        for k in range(i1 - i0):
            ex = ox + (i0 + k + 0.5) * res - ax
            now = row[k]
            d = np.float32(math.sqrt(ex * ex + e2y))
            row[k] = d if d < now else now
        return
    py = ey0 * dy
    for k in range(i1 - i0):
        # branch-free (the loop vectorises): float32(d) <= a float32 `now` iff d <= now
        cx = ox + (i0 + k + 0.5) * res
        t = min(max(((cx - ax) * dx + py) / ll, 0.0), 1.0)
        ex = cx - ax - t * dx
        ey = ey0 - t * dy
        now = row[k]
        d = np.float32(math.sqrt(ex * ex + ey * ey))
        row[k] = d if d < now else now


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _rows(y0: float, y1: float, oy: float, inv: float, h: int) -> tuple[int, int]:
    """The rows whose centres lie in [y0, y1]."""
    return max(math.ceil((y0 - oy) * inv - 0.5), 0), min(math.floor((y1 - oy) * inv - 0.5) + 1, h)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _one(
    dist: np.ndarray,
    ox: float,
    oy: float,
    res: float,
    c: float,
    ax: float,
    ay: float,
    bx: float,
    by: float,
    start: int,
    wx: float,
    wy: float,
    end: bool,
) -> None:
    """One segment a-b (in the frame of `dist`, rows = y): the cells whose nearest point of
    it is inside it (its band), around a (`start`: 0 none, 1 half a disc, 2 the wedge outside
    the band and the previous segment's, whose direction from a is w) and around b (`end`:
    half a disc). A point (a = b): a disc."""
    h = dist.shape[0]
    inv = 1.0 / res
    dx, dy = bx - ax, by - ay
    ll = dx * dx + dy * dy
    if ll == 0.0:
        j0, j1 = _rows(ay - c, ay + c, oy, inv, h)
        for j in range(j0, j1):
            y = oy + (j + 0.5) * res
            lo, hi = _disc(ax, ay, y, c)
            _cells(dist, j, lo, hi, ox, y, res, inv, ax, ay, dx, dy, ll)
        return
    length = math.sqrt(ll)
    ux, uy = dx / length, dy / length
    ext = c * abs(ux)
    j0, j1 = _rows(min(ay, by) - ext - _EPS, max(ay, by) + ext + _EPS, oy, inv, h)
    for j in range(j0, j1):
        y = oy + (j + 0.5) * res
        lo, hi = -math.inf, math.inf
        lo, hi = _cut(lo, hi, -ux, -uy, ax, ay, y, _EPS)
        lo, hi = _cut(lo, hi, ux, uy, bx, by, y, _EPS)
        lo, hi = _cut(lo, hi, -uy, ux, ax, ay, y, c)
        lo, hi = _cut(lo, hi, uy, -ux, ax, ay, y, c)
        _cells(dist, j, lo, hi, ox, y, res, inv, ax, ay, dx, dy, ll)
    if start == 2:
        r1x, r1y = -uy, ux
        if r1x * wx + r1y * wy > 0.0:
            r1x, r1y = uy, -ux
        r2x, r2y = -wy, wx
        if r2x * ux + r2y * uy > 0.0:
            r2x, r2y = wy, -wx
        y0 = min(0.0, r1y, r2y)
        y1 = max(0.0, r1y, r2y)
        if uy <= 0.0 and wy <= 0.0:
            y1 = 1.0
        if uy >= 0.0 and wy >= 0.0:
            y0 = -1.0
    else:
        y0 = -1.0 if uy >= 0.0 else -abs(ux)
        y1 = 1.0 if uy <= 0.0 else abs(ux)
    if start > 0:
        j0, j1 = _rows(ay + c * y0 - _EPS, ay + c * y1 + _EPS, oy, inv, h)
        for j in range(j0, j1):
            y = oy + (j + 0.5) * res
            lo, hi = _disc(ax, ay, y, c)
            lo, hi = _cut(lo, hi, ux, uy, ax, ay, y, _EPS)
            if start == 2:
                lo, hi = _cut(lo, hi, wx, wy, ax, ay, y, _EPS)
            _cells(dist, j, lo, hi, ox, y, res, inv, ax, ay, dx, dy, ll)
    if end:
        y0 = -1.0 if uy <= 0.0 else -abs(ux)
        y1 = 1.0 if uy >= 0.0 else abs(ux)
        j0, j1 = _rows(by + c * y0 - _EPS, by + c * y1 + _EPS, oy, inv, h)
        for j in range(j0, j1):
            y = oy + (j + 0.5) * res
            lo, hi = _disc(bx, by, y, c)
            lo, hi = _cut(lo, hi, -ux, -uy, bx, by, y, _EPS)
            _cells(dist, j, lo, hi, ox, y, res, inv, ax, ay, dx, dy, ll)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def stamp_segments(
    dist: np.ndarray, origin: np.ndarray, res: float, seg: np.ndarray, cap: float
) -> None:
    """Lower `dist` (H x W, row = y) at every cell centre within `cap` of one of the segments
    `seg` (N x 4: x0, y0, x1, y1; a point when both ends coincide) to the exact distance to
    it: a truncated Euclidean distance field of surfaces, built segment by segment (each
    touches only the cells around it), so that a map grows by one scan without a rebuild and
    its distances have no ripple between a surface's samples.

    Each cell is stamped only by the segments that can be nearest to it: a segment's band
    (the cells whose nearest point of it lies inside it), and around a vertex only the wedge
    outside the bands of both segments that meet there (half a disc at a surface's ends, a
    disc for a point). Consecutive returns of one surface are centimetres apart, so a disc of
    `cap` around every segment stamped each cell dozens of times; the result is the same to
    the bit (every cell's nearest segment still stamps it, with the same arithmetic)."""
    n = seg.shape[0]
    c = cap + _EPS
    dist_t = dist.T
    for k in range(n):
        ax, ay, bx, by = seg[k, 0], seg[k, 1], seg[k, 2], seg[k, 3]
        start, wx, wy = 1, 0.0, 0.0
        if k > 0 and seg[k - 1, 2] == ax and seg[k - 1, 3] == ay:
            px, py = seg[k - 1, 0] - ax, seg[k - 1, 1] - ay
            lp = math.sqrt(px * px + py * py)
            if lp > 0.0:
                start, wx, wy = 2, px / lp, py / lp
        end = not (
            k + 1 < n
            and seg[k + 1, 0] == bx
            and seg[k + 1, 1] == by
            and (seg[k + 1, 2] != bx or seg[k + 1, 3] != by)
        )
        # rows along the band: a band across the rows (a segment along x) runs by columns
        if abs(bx - ax) > abs(by - ay):
            _one(dist_t, origin[1], origin[0], res, c, ay, ax, by, bx, start, wy, wx, end)
        else:
            _one(dist, origin[0], origin[1], res, c, ax, ay, bx, by, start, wx, wy, end)
