"""World geometry and vectorized ray casting.

A world is wall segments (N x 4: x0, y0, x1, y1) with a material each (opaque wall or glass)
and round obstacles (M x 3: x, y, r). `cast` intersects every beam of a chunk of poses with
every segment and circle at once (broadcast chunk x beams x segments, min over segments),
chunked so that the temporaries stay small, and culls segments out of reach of each chunk.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
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
) -> Hits:
    """Cast rays from `origins` (P x 2) at `headings` (P,) + beam `angles` (B,).

    Work is broadcast over a chunk of poses x beams x segments; the chunk size keeps each
    temporary near `chunk_elements` values (cache sized). Segments and circles farther than
    `max_range` from every origin of a chunk are dropped for that chunk.
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
    wall_ids, pane_ids = np.flatnonzero(~is_glass), np.flatnonzero(is_glass)
    circles = world.circles
    n_obj = max(1, len(world.segments) + len(circles))
    step = max(1, chunk_elements // (n_beams * n_obj))
    for start in range(0, n_poses, step):
        sl = slice(start, start + step)
        o = origins[sl]
        lo, hi = o.min(axis=0) - max_range, o.max(axis=0) + max_range
        directions = headings[sl, None] + angles[None, :]
        dx, dy = np.cos(directions).astype(np.float32), np.sin(directions).astype(np.float32)
        # work in chunk-local coordinates: small numbers keep float32 exact enough
        centre = o.mean(axis=0)
        oc = (o - centre).astype(np.float32)
        shift = np.tile(centre, 2)

        ids = wall_ids[_segments_near(world.segments[wall_ids], lo, hi)]
        r, k = _hit_segments(world.segments[ids] - shift, oc, dx, dy)
        obj = np.where(np.isfinite(r), ids[k] if len(ids) else -1, -1)
        if len(circles):
            cids = np.flatnonzero(_circles_near(circles, lo, hi))
            rc, kc = _hit_circles(circles[cids] - np.array([*centre, 0.0]), oc, dx, dy)
            closer = rc < r
            r = np.where(closer, rc, r)
            obj = np.where(closer, len(world.segments) + cids[kc] if len(cids) else -1, obj)
        hits.opaque[sl], hits.opaque_id[sl] = r, obj

        ids = pane_ids[_segments_near(world.segments[pane_ids], lo, hi)]
        if len(ids):
            g, k = _hit_segments(world.segments[ids] - shift, oc, dx, dy)
            seg = world.segments[ids[k]]
            ex, ey = seg[..., 2] - seg[..., 0], seg[..., 3] - seg[..., 1]
            cosine = np.abs(dx * ey - dy * ex) / np.hypot(ex, ey)
            in_front = g < r
            hits.glass[sl] = np.where(in_front, g, np.inf)
            hits.glass_cos[sl] = np.where(in_front, cosine, 0.0)
    return hits


def _segments_near(seg: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    smin = np.minimum(seg[:, :2], seg[:, 2:])
    smax = np.maximum(seg[:, :2], seg[:, 2:])
    return np.all((smax >= lo) & (smin <= hi), axis=1)


def _circles_near(circles: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    xy, r = circles[:, :2], circles[:, 2:3]
    return np.all((xy + r >= lo) & (xy - r <= hi), axis=1)


def _hit_segments(
    seg: np.ndarray, o: np.ndarray, dx: np.ndarray, dy: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit range (P x B) of rays o + t d with segments, and which segment (index)."""
    n_poses, n_beams = dx.shape
    if len(seg) == 0:
        return np.full((n_poses, n_beams), np.inf, np.float32), np.zeros(dx.shape, np.intp)
    seg = seg.astype(np.float32)
    ex, ey = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]  # (N,)
    wx = seg[None, :, 0] - o[:, 0:1]  # (P, N): segment start relative to the origin
    wy = seg[None, :, 1] - o[:, 1:2]
    num_t = (wx * ey - wy * ex)[:, None, :]  # (P, 1, N)
    dxe, dye = dx[:, :, None], dy[:, :, None]
    denom = dxe * ey - dye * ex  # (P, B, N)
    num_s = wx[:, None, :] * dye - wy[:, None, :] * dxe
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num_t / denom
        s = num_s / denom
    t = np.where((s >= 0) & (s <= 1) & (t > 0), t, np.float32(np.inf))
    return _nearest(t)


def _hit_circles(
    c: np.ndarray, o: np.ndarray, dx: np.ndarray, dy: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit range (P x B) of rays with circles (entering hits only), and which."""
    if len(c) == 0:
        return np.full(dx.shape, np.inf, np.float32), np.zeros(dx.shape, np.intp)
    c = c.astype(np.float32)
    wx = o[:, 0:1] - c[None, :, 0]  # (P, M)
    wy = o[:, 1:2] - c[None, :, 1]
    cc = (wx * wx + wy * wy - c[None, :, 2] ** 2)[:, None, :]  # (P, 1, M)
    b = dx[:, :, None] * wx[:, None, :] + dy[:, :, None] * wy[:, None, :]  # (P, B, M)
    disc = b * b - cc
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)
    t = np.where((disc >= 0) & (t > 0), t, np.float32(np.inf))
    return _nearest(t)


def _nearest(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k = np.argmin(t, axis=2)
    return np.take_along_axis(t, k[:, :, None], axis=2)[:, :, 0], k
