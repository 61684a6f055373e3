"""Loop candidates by appearance: place recognition that does not depend on the drifted pose.

The position-based candidates (`toolkit.slam.loops.candidates`) look for an earlier keyframe
near the later one on the trajectory; after a long stretch without loops the drift puts a
revisit 6-37 m off (freiburg-campus, infinite-corridor; docs/journal/maps.md sessions
17-18), beyond any window, and the right pair is never proposed. Here each keyframe's local
map (its neighbours within `path` m of path, placed by the trajectory, which is locally right)
is described by a Scan Context (Kim & Kim, IROS 2018) in 2D: a polar grid of `rings` x
`sectors` cells around the keyframe, each how many of the map's points (one per `voxel` cell)
fall in it (kept as bytes: a million-scan log's 100,000 keyframes in 120 MB), compared by
their square roots. Its ring key (each ring's mean over the sectors) does not
change with the heading: the earlier keyframes nearest to a query by ring key (a k-d tree)
are compared by the full descriptor over every circular shift of the sectors (the mean
cosine distance of the columns both occupy), whose best shift is the relative heading.
The nearest few that pass `max_distance`, and that the trajectory puts close enough for
the drift over the path between them to explain (`drift`: a corridor without revisit looks
alike everywhere, and its places tens of metres apart were verified in vain), are verified
by the loop closer's own seed-free correlative search (`LoopCloser.verify`) from that
heading and no translation, over a `window` m and `turn` rad, and from the opposite heading
too (a corridor or a symmetric room looks alike turned round: the better match wins, and
the other scoring within `max_ambiguity` of it refuses it), with every test of a loop
(inliers, ambiguity, anchors) and no corridor loops (a match along a corridor says nothing
about where along it; another corridor alike is the worse failure). The loops then face the
same consistency test and graph residual test as the others (`toolkit.slam.pipeline`).
"""

from __future__ import annotations

from collections.abc import Container
from dataclasses import dataclass, replace

import numpy as np

from toolkit.se2 import wrap
from toolkit.slam.loops import Loop, LoopCloser, LoopConfig


@dataclass(frozen=True)
class RecognitionConfig:
    """Place recognition's parameters; lengths in m, angles in rad."""

    path: float = 10.0  # a keyframe's local map: scans within this path distance of it ...
    scans: int = 24  # ... at most this many of them, evenly along it
    voxel: float = 0.2  # one point per cell of this size
    rings: int = 20  # polar grid: rings of range / rings m each, out to ...
    range: float = 20.0  # ... this range
    sectors: int = 60  # ... and sectors of 2 pi / sectors
    min_points: int = 80  # a local map with fewer points is not described
    gap: float = 30.0  # candidates lie at least this far back along the path
    neighbours: int = 150  # ring-key neighbours looked up per query (then those far back kept)
    compared: int = 150  # ... of which this many nearest are compared by the full descriptor
    verified: int = 2  # ... and at most this many within `max_distance` verified
    max_distance: float = 0.35  # full descriptor distance (0 alike .. 1 unlike)
    every: float = 2.0  # a query every this much path
    window: float = 3.0  # verification: translation window (+-) around no translation ...
    # ... and heading window (+-) around the descriptor's, and around its opposite (below pi
    # / 2; from pi / 2 one search: every heading at pi, 1.6x the loop stage and +280 MB peak
    # on a 200,000-scan log; docs/journal/maps.md, session 19)
    turn: float = 0.35
    # the drift gate: a candidate pair is verified only if the trajectory puts the two poses
    # within `drift` times the position candidates' uncertainty (`LoopConfig.radius` +
    # `LoopConfig.growth` per metre of path between them) of each other; the rest cannot be
    # the same place given the drift (a corridor without revisit looks alike everywhere).
    # inf: no gate. (docs/journal/maps.md, session 19: the gate)
    drift: float = 4.0
    # True: the opposite heading is searched only when the descriptor's heading passes the
    # loop tests: a refused pair stays refused unless its opposite would win and pass (in the
    # mapper's rounds on five logs x drift seeds 0-2, 1,400 pairs, 268 opposites won and none
    # passed; over a front end's trajectory it happens: seattle seed 0 loses a true loop);
    # recognition's searches -36%, the loop stage's CPU -6% on the ten logs x seeds 0-35, poses
    # unchanged in all 360 runs. Expert, off: docs/journal/maps.md, session 22 (verify22)
    opposite_if_passed: bool = False
    # the descriptors' spectra (`spectra`, 10 KB a keyframe) are computed once for the log
    # when they fit in this many bytes (6,000 keyframes), else per query: the same distances
    spectra_bytes: int = 64_000_000


def describe(points: np.ndarray, config: RecognitionConfig) -> np.ndarray:
    """The 2D Scan Context of `points` (N x 2, in the keyframe's frame): rings x sectors,
    the point count per polar cell (uint8, at most 255), beyond `range` left out."""
    out: np.ndarray = describe_many(points, np.array([len(points)]), config)[0]
    return out


#: the square root of every count a cell can hold (the descriptors are uint8)
_ROOT = np.sqrt(np.arange(256, dtype=np.float64))


def ring_key(desc: np.ndarray, chunk: int = 1024) -> np.ndarray:
    """Each ring's mean over its sectors of the counts' square roots (..., rings): the same
    at any heading. A stack of descriptors `chunk` at a time (all at once in float64 was
    +280 MB peak on a 200,000-scan log's 15,000 keyframes)."""
    if desc.ndim < 3:
        out: np.ndarray = _ROOT[desc].mean(axis=-1)
        return out
    parts = [_ROOT[desc[i : i + chunk]].mean(axis=-1) for i in range(0, len(desc), chunk)]
    return np.concatenate(parts) if parts else np.zeros((0, desc.shape[-2]))


def _unit(d: np.ndarray) -> np.ndarray:
    """Each column (sector) of descriptors `d` (..., rings, sectors) scaled to unit length
    over its rings (0 where empty)."""
    n = np.linalg.norm(d, axis=-2, keepdims=True)
    out: np.ndarray = np.where(n > 0, d / np.where(n > 0, n, 1.0), 0.0)
    return out


def spectra(desc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What `shift_distances` needs of descriptors `desc` (..., rings, sectors counts): the
    spectrum along the sectors of each ring of the unit columns (of the counts' square
    roots), and of which columns hold points."""
    root = _ROOT[desc]
    return np.fft.rfft(_unit(root), axis=-1), np.fft.rfft(
        (root.sum(axis=-2) > 0).astype(np.float64), axis=-1
    )


def shift_distances(
    query: np.ndarray,
    refs: np.ndarray | None,
    ref_spectra: tuple[np.ndarray, np.ndarray] | None = None,
    query_spectra: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Scan Context distance of `query` (R x S counts) to each of `refs` (M x R x S) at every
    circular shift s of the sectors (M x S): 1 - the mean cosine similarity (of the counts'
    square roots) of the columns
    both hold points in, with ref's column j - s against query's column j (1 where none
    is shared); the query's heading in the ref's frame at shift s is -s sectors. One FFT
    per ring for all shifts. `ref_spectra`: the refs' `spectra`, computed once for many
    queries (the same numbers: each ring's transform is its own), instead of `refs`;
    `query_spectra` likewise the query's (a row of those held for the log)."""
    q, qa = query_spectra if query_spectra is not None else spectra(query)
    c, ca = ref_spectra if ref_spectra is not None else spectra(np.asarray(refs))
    sectors = query.shape[-1]
    # corr[m, s] = sum_j sum_r q[r, j] c[m, r, j - s]
    corr = np.fft.irfft((q[None] * np.conj(c)).sum(axis=-2), n=sectors, axis=-1)
    shared = np.fft.irfft(qa[None] * np.conj(ca), n=sectors, axis=-1)
    shared = np.rint(shared)
    out: np.ndarray = np.where(shared > 0, 1.0 - corr / np.maximum(shared, 1.0), 1.0)
    return out


def keyframe_descriptors(
    closer: LoopCloser,
    keys: np.ndarray,
    poses: np.ndarray,
    along: np.ndarray,
    config: RecognitionConfig,
    chunk: int = 128,
) -> tuple[np.ndarray, np.ndarray]:
    """Every keyframe's descriptor (K x rings x sectors) of its local map (`path`, `scans`),
    and whether it has one (K,: at least `min_points` points). `chunk` keyframes at a time:
    their maps' points in one numba call (`LoopCloser.voxelled_maps`) and described
    together (`describe_many`), the same counts as one by one."""
    desc = np.zeros((len(keys), config.rings, config.sectors), dtype=np.uint8)
    ok = np.zeros(len(keys), dtype=bool)
    lo = np.searchsorted(along[keys], along[keys] - config.path, side="left")
    hi = np.searchsorted(along[keys], along[keys] + config.path, side="right")
    for start in range(0, len(keys), chunk):
        qs = np.arange(start, min(start + chunk, len(keys)))
        groups = []
        for q in qs:
            near = keys[lo[q] : hi[q]]
            groups.append(
                near[np.linspace(0, len(near) - 1, min(len(near), config.scans)).astype(np.int64)]
            )
        pts, counts = closer.voxelled_maps(keys[qs], groups, poses, config.voxel)
        enough = counts >= config.min_points
        desc[qs[enough]] = describe_many(pts, counts, config)[enough]
        ok[qs] = enough
    return desc, ok


def describe_many(points: np.ndarray, counts: np.ndarray, config: RecognitionConfig) -> np.ndarray:
    """`describe` of many point sets at once: `points` (N x 2) holds them one after the
    other, `counts` how many each has (G,); G x rings x sectors, the same counts as one by
    one (the same arithmetic, point by point)."""
    group = np.repeat(np.arange(len(counts)), counts)
    r = np.hypot(points[:, 0], points[:, 1])
    keep = r < config.range
    ring = (r[keep] * (config.rings / config.range)).astype(np.int64)
    bearing = np.arctan2(points[keep, 1], points[keep, 0]) % (2 * np.pi)
    sector = np.minimum(
        (bearing * (config.sectors / (2 * np.pi))).astype(np.int64), config.sectors - 1
    )
    cells = config.rings * config.sectors
    code = group[keep] * cells + ring * config.sectors + sector
    tally = np.bincount(code, minlength=len(counts) * cells)
    out: np.ndarray = np.minimum(tally, 255).astype(np.uint8)
    return out.reshape(len(counts), config.rings, config.sectors)


def _stacked_spectra(desc: np.ndarray, chunk: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """`spectra` of a stack of descriptors, `chunk` at a time (the float64 square roots of
    all at once would double the peak)."""
    parts = [spectra(desc[i : i + chunk]) for i in range(0, len(desc), chunk)]
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def within_drift(
    apart: np.ndarray, path: np.ndarray, config: RecognitionConfig, reach: tuple[float, float]
) -> np.ndarray:
    """The drift gate: whether two poses `apart` m from each other with `path` m of path
    between them lie within `drift` x (`reach[0]` + `reach[1]` per metre of path)."""
    out: np.ndarray = apart <= config.drift * (reach[0] + reach[1] * path)
    return out


def any_within_drift(
    keys: np.ndarray,
    poses: np.ndarray,
    along: np.ndarray,
    config: RecognitionConfig,
    reach: tuple[float, float],
    max_pairs: int = 20_000_000,
    rows: int = 256,
) -> bool:
    """Whether any two keyframes more than `gap` apart along the path lie within the drift
    gate's bound of each other: if none does, no candidate by appearance can be verified and
    the descriptors need not be computed (a corridor without revisit). True, without
    looking, when there are more than `max_pairs` pairs (a long log: the descriptors pay).
    `rows` keyframes at a time against only the earlier ones more than `gap` back (the keys
    are in path order): the first block holding a pair ends the walk (the whole square at
    once was a quarter of a second on a 2,000-keyframe log that has a revisit early)."""
    if not np.isfinite(config.drift) or len(keys) < 2:
        return len(keys) >= 2
    if len(keys) ** 2 > max_pairs:
        return True
    ka = along[keys]
    xy = poses[keys, :2]
    for start in range(0, len(keys), rows):
        b = slice(start, start + rows)
        # the earlier keys more than `gap` back of the block's last one (1 m to spare, so
        # that rounding cannot leave one out): beyond them no pair of the block is `gap` apart
        cols = int(np.searchsorted(ka, ka[b][-1] - config.gap + 1.0, side="right"))
        if cols == 0:
            continue
        path = ka[b, None] - ka[None, :cols]
        apart = np.hypot(xy[b, None, 0] - xy[None, :cols, 0], xy[b, None, 1] - xy[None, :cols, 1])
        if ((path > config.gap) & within_drift(apart, path, config, reach)).any():
            return True
    return False


def candidates(
    desc: np.ndarray,
    ok: np.ndarray,
    keys: np.ndarray,
    along: np.ndarray,
    config: RecognitionConfig,
    skip: np.ndarray | None = None,
    poses: np.ndarray | None = None,
    reach: tuple[float, float] = (np.inf, 0.0),
) -> list[tuple[int, int, float, float]]:
    """(earlier scan, later scan, descriptor distance, relative heading of the later in the
    earlier's frame) for a query keyframe every `every` m of path (none within `every` of a
    scan in `skip`, already closed): the earlier keyframes more than `gap` back whose ring
    keys are nearest, compared by the full descriptor at every shift; the best `verified`
    within `max_distance`, of which those `poses` put within `drift` x (`reach[0]` +
    `reach[1]` per metre of path between) of each other (all without `poses`)."""
    ka = along[keys]
    kp = poses[keys, :2] if poses is not None else None
    idx = np.nonzero(ok)[0]
    if len(idx) < 2:
        return []
    # on use: scipy.spatial costs 0.15-0.5 s to import, and a log whose keyframes are never
    # candidates (none within the drift gate) does not need it
    from scipy.spatial import cKDTree  # noqa: PLC0415

    rings = ring_key(desc[idx])
    tree = cKDTree(rings)
    # every described keyframe's spectra once (each ref is compared with many queries), when
    # they fit `spectra_bytes`; else per query, as the refs come
    per_key = 16 * (config.rings + 1) * (config.sectors // 2 + 1)
    held = None
    if len(idx) * per_key <= config.spectra_bytes:
        held = _stacked_spectra(desc[idx])
    closed = np.sort(along[skip]) if skip is not None and len(skip) else np.zeros(0)
    step = 2 * np.pi / config.sectors
    out: list[tuple[int, int, float, float]] = []
    # the queries (which do not depend on what is found), then their ring-key neighbours in
    # one call of the tree
    queries: list[int] = []
    next_at = 0.0
    for m, q in enumerate(idx):
        if ka[q] < next_at or ka[q] < config.gap:
            continue
        next_at = ka[q] + config.every
        if len(closed):
            at = np.searchsorted(closed, ka[q])
            if (np.abs(closed[max(at - 1, 0) : at + 1] - ka[q]) < config.every).any():
                continue
        queries.append(m)
    if not queries:
        return []
    k = min(config.neighbours, len(idx))
    _, neighbours = tree.query(rings[queries], k=k)
    neighbours = np.asarray(neighbours).reshape(len(queries), -1)
    for m, nn in zip(queries, neighbours, strict=True):
        q = idx[m]
        near = idx[nn]
        near = near[ka[q] - ka[near] > config.gap][: config.compared]
        if len(near) == 0:
            continue
        if held is not None:
            at = np.searchsorted(idx, near)
            # the query is a described keyframe too: its spectra are held as well
            d = shift_distances(desc[q], None, (held[0][at], held[1][at]), (held[0][m], held[1][m]))
        else:
            d = shift_distances(desc[q], desc[near])
        best = d.argmin(axis=1)
        dist = d[np.arange(len(near)), best]
        order = np.argsort(dist)[: config.verified]
        order = order[dist[order] <= config.max_distance]
        if kp is not None and len(order):
            # the drift gate (`RecognitionConfig.drift`), over the query's few at once
            apart = np.hypot(*(kp[near[order]] - kp[q]).T)
            order = order[within_drift(apart, ka[q] - ka[near[order]], config, reach)]
        for m in order:
            heading = float(wrap(-best[m] * step))
            out.append((int(keys[near[m]]), int(keys[q]), float(dist[m]), heading))
    return out


def find(
    closer: LoopCloser,
    keys: np.ndarray,
    poses: np.ndarray,
    along: np.ndarray,
    loop_config: LoopConfig,
    config: RecognitionConfig | None = None,
    skip: np.ndarray | None = None,
    known: Container[tuple[int, int]] = (),
) -> list[Loop]:
    """Appearance candidates (`candidates`) verified by `closer` with `loop_config`'s tests,
    from the descriptor's heading and its opposite over `window` / `turn`, no corridor loops;
    rejected ones too. Pairs in `known` (verified before) are left out."""
    cfg = config or RecognitionConfig()
    reach = (loop_config.radius, loop_config.growth)
    if not any_within_drift(keys, poses, along, cfg, reach):
        return []
    desc, ok = keyframe_descriptors(closer, keys, poses, along, cfg)
    verify_cfg = replace(loop_config, corridor=False, turn=cfg.turn)
    todo = [
        (a, b, heading)
        for a, b, _, heading in candidates(desc, ok, keys, along, cfg, skip, poses, reach)
        if (a, b) not in known
    ]

    def check(pair: tuple[int, int, float]) -> Loop | None:
        a, b, heading = pair
        prediction = np.array([0.0, 0.0, heading])
        # the pair's points once for both headings
        points = closer.pair_points(a, b, poses, along, keys, verify_cfg)
        if points is None:
            return None
        staged = closer.search_coarse(cfg.window, verify_cfg, prediction, points)
        if staged is None:
            return None
        both = cfg.turn < np.pi / 2 and not cfg.opposite_if_passed
        flipped = np.array([0.0, 0.0, wrap(heading + np.pi)])
        other_staged = None
        early = closer.coarse_refusal(a, b, cfg.window, prediction, points, staged)
        if early is not None and both:
            # refused whatever the fine levels find only when the opposite heading's winner
            # would be refused too (or there is none): it wins when it scores higher
            other_staged = closer.search_coarse(cfg.window, verify_cfg, flipped, points)
            if other_staged is not None and (
                closer.coarse_refusal(a, b, cfg.window, flipped, points, other_staged) is None
            ):
                early = None
            else:
                early.reason += ", both headings"
        if early is not None:
            early.recognised = True
            return early
        searched = closer.search_fine(staged)
        other, loop = None, None
        if cfg.turn < np.pi / 2 and cfg.opposite_if_passed:
            # the descriptor's heading tested first: refused, the pair is refused without
            # searching the opposite (`opposite_if_passed`)
            loop = closer.judge(
                a, b, cfg.window, poses, along, keys, verify_cfg, prediction, points, searched
            )
            if not loop.accepted:
                loop.recognised = True
                return loop
        if cfg.turn < np.pi / 2:
            # a narrow heading window: the opposite heading searched too (a corridor or a
            # symmetric room looks alike turned round); the better wins, and the other
            # scoring within `max_ambiguity` of it is an ambiguity. Only the winner is
            # tested (`judge`): the other's score is all that is used of it
            if other_staged is None:
                other_staged = closer.search_coarse(cfg.window, verify_cfg, flipped, points)
            other = None if other_staged is None else closer.search_fine(other_staged)
            if other is not None and other[0].score > searched[0].score:
                prediction, searched, other = flipped, other, searched
                loop = None
        if loop is None:
            loop = closer.judge(
                a, b, cfg.window, poses, along, keys, verify_cfg, prediction, points, searched
            )
        if other is not None and other[0].score > loop_config.max_ambiguity * loop.score:
            loop.accepted = loop.fit = False
            loop.reason = "; ".join(
                r
                for r in (loop.reason, f"opposite heading scores {other[0].score / loop.score:.2f}")
                if r
            )
        loop.recognised = True
        return loop

    return closer.each(check, todo)


__all__ = [
    "RecognitionConfig",
    "any_within_drift",
    "candidates",
    "describe",
    "describe_many",
    "find",
    "keyframe_descriptors",
    "ring_key",
    "shift_distances",
    "spectra",
    "within_drift",
]
