"""World geometry and vectorized ray casting.

A world is wall segments (N x 4: x0, y0, x1, y1) with a material each (opaque wall or glass)
and round obstacles (M x 3: x, y, r). `cast` intersects every beam of a chunk of poses with
every segment and circle at once (broadcast chunk x beams x segments, min over segments),
chunked so that the temporaries stay small, and culls segments out of reach of each chunk.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

WALL = 0
GLASS = 1

Point = tuple[float, float]


@dataclass
class World:
    """Segments with materials, and circles (columns, posts)."""

    segments: np.ndarray  # (N, 4) float64: x0, y0, x1, y1
    material: np.ndarray  # (N,) int8: WALL or GLASS
    circles: np.ndarray  # (M, 3) float64: x, y, r

    def __post_init__(self) -> None:
        self.segments = np.asarray(self.segments, dtype=np.float64).reshape(-1, 4)
        self.material = np.asarray(self.material, dtype=np.int8).reshape(-1)
        self.circles = np.asarray(self.circles, dtype=np.float64).reshape(-1, 3)
        if len(self.material) != len(self.segments):
            raise ValueError("one material per segment")

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """xmin, ymin, xmax, ymax over segments and circles."""
        xs = np.concatenate(
            [
                self.segments[:, [0, 2]].ravel(),
                self.circles[:, 0] - self.circles[:, 2],
                self.circles[:, 0] + self.circles[:, 2],
            ]
        )
        ys = np.concatenate(
            [
                self.segments[:, [1, 3]].ravel(),
                self.circles[:, 1] - self.circles[:, 2],
                self.circles[:, 1] + self.circles[:, 2],
            ]
        )
        return float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max())


@dataclass
class WorldBuilder:
    """Walls with openings (doors into rooms, glass panes, plain gaps), boxes and circles."""

    segments: list[tuple[float, float, float, float]] = field(default_factory=list)
    materials: list[int] = field(default_factory=list)
    circles: list[tuple[float, float, float]] = field(default_factory=list)

    def segment(self, p0: Point, p1: Point, material: int = WALL) -> None:
        self.segments.append((p0[0], p0[1], p1[0], p1[1]))
        self.materials.append(material)

    def polyline(self, points: Sequence[Point], material: int = WALL) -> None:
        for a, b in itertools.pairwise(points):
            self.segment(a, b, material)

    def box(self, x0: float, y0: float, x1: float, y1: float) -> None:
        """A closed axis-aligned rectangle (a table, a square column)."""
        self.polyline([(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)])

    def circle(self, x: float, y: float, r: float) -> None:
        self.circles.append((x, y, r))

    def wall(
        self,
        p0: Point,
        p1: Point,
        openings: Sequence[tuple[float, float, str]] = (),
        outward: Point = (0.0, 0.0),
        room: tuple[float, float] = (4.0, 3.0),
    ) -> None:
        """A straight wall from p0 to p1 with openings at (s0, s1, kind), s in m from p0.

        kind "glass": a glass pane; "gap": nothing; "door": a gap with a room behind it, a
        box `room` = (width along the wall, depth along `outward`) centred on the door.
        """
        a, b = np.asarray(p0, float), np.asarray(p1, float)
        length = float(np.hypot(*(b - a)))
        u = (b - a) / length
        n = np.asarray(outward, float)

        def at(s: float) -> tuple[float, float]:
            q = a + u * s
            return float(q[0]), float(q[1])

        s = 0.0
        for s0, s1, kind in sorted(openings):
            if s0 > s:
                self.segment(at(s), at(s0))
            if kind == "glass":
                self.segment(at(s0), at(s1), GLASS)
            elif kind == "door":
                width, depth = room
                c = 0.5 * (s0 + s1)
                corners = [a + u * (c - width / 2), a + u * (c + width / 2)]
                far = [q + n * depth for q in corners]
                pts = [corners[0], far[0], far[1], corners[1]]
                self.polyline([(float(q[0]), float(q[1])) for q in pts])
            elif kind != "gap":
                raise ValueError(f"unknown opening kind {kind!r}")
            s = s1
        if s < length:
            self.segment(at(s), at(length))

    def build(self) -> World:
        return World(np.array(self.segments), np.array(self.materials), np.array(self.circles))


@dataclass
class Hits:
    """Per beam: nearest opaque range and what it hit, nearest glass range and |cos| of its
    incidence angle. inf where a ray meets nothing of that kind (object -1); glass farther
    than the opaque hit is inf. Objects: segment index, or len(segments) + circle index.
    """

    opaque: np.ndarray  # (P, B) float32
    opaque_id: np.ndarray  # (P, B) int32
    glass: np.ndarray  # (P, B) float32
    glass_cos: np.ndarray  # (P, B) float32


def cast(
    world: World,
    origins: np.ndarray,
    headings: np.ndarray,
    angles: np.ndarray,
    max_range: float,
    chunk_elements: int = 1 << 18,
    near: float = 8.0,
    progress: Callable[[int], object] | None = None,
) -> Hits:
    """Cast rays from `origins` (P x 2) at `headings` (P,) + beam `angles` (B,).

    Work is broadcast over a chunk of poses x beams x objects, in passes of growing reach R
    (`near`, 3 `near`, ... up to `max_range`): each pass takes the objects within R of the
    chunk's origins, so a hit closer than R is exact (any closer hit would lie on one of
    them); the rays left without one go on to the next pass. Indoors most beams end on a
    wall nearby, so the far passes are small. Temporaries stay near `chunk_elements` values
    (cache sized). `progress(n)` is called after each chunk of n poses.
    """
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 2)
    headings = np.asarray(headings, dtype=np.float64).reshape(-1)
    angles = np.asarray(angles, dtype=np.float64).reshape(-1)
    n_poses, n_beams = len(origins), len(angles)
    hits = Hits(
        opaque=np.full((n_poses, n_beams), np.inf, np.float32),
        opaque_id=np.full((n_poses, n_beams), -1, np.int32),
        glass=np.full((n_poses, n_beams), np.inf, np.float32),
        glass_cos=np.zeros((n_poses, n_beams), np.float32),
    )
    if n_poses == 0:
        return hits

    is_glass = world.material == GLASS
    walls = _Objects(world, np.flatnonzero(~is_glass), with_circles=True)
    panes = _Objects(world, np.flatnonzero(is_glass), with_circles=False)
    reach = min(near, max_range)
    step = max(1, chunk_elements // (n_beams * 32))
    for start in range(0, n_poses, step):
        sl = slice(start, start + step)
        o = origins[sl]
        omin, omax = o.min(axis=0), o.max(axis=0)
        directions = headings[sl, None] + angles[None, :]
        dx, dy = np.cos(directions).astype(np.float32), np.sin(directions).astype(np.float32)
        # work in chunk-local coordinates: small numbers keep float32 exact enough
        centre = o.mean(axis=0)
        ox, oy = (o - centre).astype(np.float32).T
        grid = (ox[:, None, None], oy[:, None, None], dx[:, :, None], dy[:, :, None])

        r, obj = walls.hit(centre, omin - reach, omax + reach, *grid)
        while reach < max_range:  # widen the reach for the rays without a hit yet
            far = ~(r <= reach)
            reach = min(reach * 3, max_range)
            if not far.any():
                continue
            pi, bi = np.nonzero(far)
            rays = (ox[pi], oy[pi], dx[pi, bi], dy[pi, bi])
            lo, hi = omin - reach, omax + reach
            k = max(1, chunk_elements // max(1, walls.count(lo, hi)))
            for j in range(0, len(pi), k):
                part = tuple(a[j : j + k, None] for a in rays)
                r_far, obj_far = walls.hit(centre, lo, hi, *part)
                r[pi[j : j + k], bi[j : j + k]] = r_far
                obj[pi[j : j + k], bi[j : j + k]] = obj_far
        hits.opaque[sl], hits.opaque_id[sl] = r, obj

        if len(panes.ids):
            g, pane = panes.hit(centre, omin - max_range, omax + max_range, *grid)
            seg = world.segments[np.maximum(pane, 0)]
            ex, ey = seg[..., 2] - seg[..., 0], seg[..., 3] - seg[..., 1]
            cosine = np.abs(dx * ey - dy * ex) / np.hypot(ex, ey)
            in_front = g < r
            hits.glass[sl] = np.where(in_front, g, np.inf)
            hits.glass_cos[sl] = np.where(in_front, cosine, 0.0)
        if progress is not None:
            progress(len(o))
    return hits


class _Objects:
    """Some of a world's segments (and its circles): nearest hits of rays, by object id."""

    def __init__(self, world: World, ids: np.ndarray, with_circles: bool) -> None:
        self.ids = ids
        self.segments = world.segments[ids]
        self.smin = np.minimum(self.segments[:, :2], self.segments[:, 2:])
        self.smax = np.maximum(self.segments[:, :2], self.segments[:, 2:])
        self.circles = world.circles if with_circles else np.zeros((0, 3))
        self.circle_base = len(world.segments)

    def _near(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        seg = np.all((self.smax >= lo) & (self.smin <= hi), axis=1)
        xy, rad = self.circles[:, :2], self.circles[:, 2:3]
        circ = np.all((xy + rad >= lo) & (xy - rad <= hi), axis=1)
        return np.flatnonzero(seg), np.flatnonzero(circ)

    def count(self, lo: np.ndarray, hi: np.ndarray) -> int:
        seg, circ = self._near(lo, hi)
        return len(seg) + len(circ)

    def hit(
        self,
        centre: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        ox: np.ndarray,
        oy: np.ndarray,
        dx: np.ndarray,
        dy: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Nearest range and object id (-1: none) of rays o + t d, origins relative to
        `centre`; arrays broadcast with a trailing object axis of length 1."""
        seg_k, circ_k = self._near(lo, hi)
        shift = np.tile(centre, 2)
        r, k = _hit_segments((self.segments[seg_k] - shift).astype(np.float32), ox, oy, dx, dy)
        obj = np.where(np.isfinite(r), self.ids[seg_k][k] if len(seg_k) else -1, -1)
        if len(circ_k):
            c = (self.circles[circ_k] - np.array([*centre, 0.0])).astype(np.float32)
            rc, kc = _hit_circles(c, ox, oy, dx, dy)
            closer = rc < r
            r = np.where(closer, rc, r)
            obj = np.where(closer, self.circle_base + circ_k[kc], obj)
        return r, obj.astype(np.int32)


def _hit_segments(
    seg: np.ndarray, ox: np.ndarray, oy: np.ndarray, dx: np.ndarray, dy: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit range of rays o + t d with segments s0 + u e (u in [0, 1]), and which.

    Origins broadcast as (..., 1) against the segments' last axis; with origins (P, 1, 1)
    and directions (P, B, 1), the numerator of t is computed once per pose and segment.
    """
    shape = np.broadcast_shapes(ox.shape, dx.shape)[:-1]
    if len(seg) == 0:
        return np.full(shape, np.inf, np.float32), np.zeros(shape, np.intp)
    ex, ey = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]
    wx, wy = seg[:, 0] - ox, seg[:, 1] - oy  # segment start relative to the origin
    num_t = wx * ey - wy * ex
    denom = dx * ey - dy * ex
    num_u = wx * dy - wy * dx
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num_t / denom
        u = num_u / denom
    t = np.where((u >= 0) & (u <= 1) & (t > 0), t, np.float32(np.inf))
    return _nearest(t)


def _hit_circles(
    c: np.ndarray, ox: np.ndarray, oy: np.ndarray, dx: np.ndarray, dy: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit range of rays with circles (entering hits only), and which circle."""
    wx, wy = ox - c[:, 0], oy - c[:, 1]
    b = dx * wx + dy * wy
    miss = wx * dy - wy * dx  # distance of the centre from the ray's line: no cancellation
    disc = c[:, 2] ** 2 - miss * miss
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)
    t = np.where((disc >= 0) & (t > 0), t, np.float32(np.inf))
    return _nearest(t)


def _nearest(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k = np.argmin(t, axis=-1)
    return np.take_along_axis(t, k[..., None], axis=-1)[..., 0], k
