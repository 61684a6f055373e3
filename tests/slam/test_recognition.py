"""Loop candidates by appearance (`toolkit.slam.recognition`): the descriptor's heading and
ranking, and infinite-corridor's worst development draw, whose revisits the drift put beyond
every window (docs/journal/maps.md, sessions 17 and 19)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

import toolkit
from tests.slam.conftest import drifted_carmen
from toolkit.metrics import evaluate
from toolkit.poses import odometry_poses, truth_poses
from toolkit.se2 import wrap
from toolkit.slam import recognition as rc
from toolkit.slam.grid import voxel_subsample
from toolkit.slam.loops import Loop, LoopCloser, LoopConfig, is_false_loop, path_length
from toolkit.slam.pipeline import SlamConfig, close_loops, keyframes_of


def _rotated(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    out: np.ndarray = points @ np.array([[c, s], [-s, c]])
    return out


def test_descriptor_heading_and_ranking() -> None:
    """A place seen from the same spot at another heading: the best shift of the descriptor
    gives the heading within a sector, and among other random places it ranks first."""
    cfg = rc.RecognitionConfig()
    rng = np.random.default_rng(3)
    places = [rng.uniform(-15, 15, (500, 2)) for _ in range(20)]
    step = 2 * np.pi / cfg.sectors
    refs = np.array([rc.describe(p, cfg) for p in places])
    for phi in (0.8, -2.0, 3.0):
        # the query is place 7 with its frame turned by phi: p_ref = R(phi) p_query
        query = rc.describe(_rotated(places[7], -phi), cfg)
        d = rc.shift_distances(query, refs)
        assert int(d.min(axis=1).argmin()) == 7
        heading = wrap(-d[7].argmin() * step)
        assert abs(wrap(heading - phi)) <= step
        # the ring key does not see the heading
        assert np.allclose(rc.ring_key(query), rc.ring_key(refs[7]), atol=0.2)


def test_real_infinite_corridor_revisits_beyond_the_window_closed_by_appearance(
    real: Path,
) -> None:
    """infinite-corridor, drift seed 14, the bench's draw 1 (development): the return from
    the western loop comes back into the east-west corridor 6-22 m off the trajectory
    (session 17), beyond the 3 m and 12 m windows: no loop ties that stretch and the ATE is
    5.2 m. Proposed by appearance the revisits close (0.34 m), and no accepted loop is false."""
    from bench.bench_slam import nudged
    from toolkit.slam.scanmap import scan_to_map

    ds = nudged(drifted_carmen(real, "infinite-corridor", seed=14), 1)
    truth = truth_poses(ds)
    assert truth is not None
    before = scan_to_map(ds).poses

    def run(on: bool) -> tuple[float, int]:
        cfg = SlamConfig()
        cfg = replace(cfg, loop=replace(cfg.loop, recognition=on))
        poses, _, _, loops, _, _ = close_loops(ds, before, cfg)
        accepted = [lp for lp in loops if lp.accepted]
        assert not [lp for lp in accepted if is_false_loop(lp, truth)]
        return float(evaluate(poses, truth)["ate"]["rmse"]), sum(lp.recognised for lp in accepted)

    ate_off, recognised_off = run(False)
    ate_on, recognised_on = run(True)
    assert recognised_off == 0 and ate_off > 3.0
    assert recognised_on >= 5 and ate_on < 0.6


def test_drift_gate_keeps_revisits_the_drift_explains_and_drops_the_rest() -> None:
    """A corridor walked out and back, keyframes every 2 m, each place with its own
    descriptor (seen the same way out and back). Walked out only with one descriptor
    everywhere (a corridor looks alike): ungated every query has candidates, gated none (the
    places lie as far apart as the path between them). Out and back with the return 15 m off:
    only the pairs with enough path between for the drift to explain 15 m (`drift` x (1 m +
    0.03 m per m)) stay, and they are the same places."""
    cfg = rc.RecognitionConfig()
    rng = np.random.default_rng(5)
    n = 60
    places = (rng.random((n, cfg.rings, cfg.sectors)) < 0.3) * rng.integers(1, 6, (n, 1, 1))
    places = places.astype(np.uint8)
    reach = (1.0, 0.03)

    # out only, alike everywhere
    keys = np.arange(n)
    along = 2.0 * keys
    poses = np.column_stack([along, np.zeros(n), np.zeros(n)])
    same = np.repeat(places[:1], n, axis=0)
    ok = np.ones(n, dtype=bool)
    assert len(rc.candidates(same, ok, keys, along, replace(cfg, drift=np.inf), None, poses, reach))
    assert rc.candidates(same, ok, keys, along, cfg, None, poses, reach) == []
    # ... known before any descriptor is computed, in one pass or in chunks
    assert not rc.any_within_drift(keys, poses, along, cfg, reach)
    assert not rc.any_within_drift(keys, poses, along, cfg, reach, max_pairs=n * n)
    assert rc.any_within_drift(keys, poses, along, replace(cfg, drift=np.inf), reach)

    # out and back, the return 15 m off across the corridor
    keys = np.arange(2 * n)
    along = 2.0 * keys
    place = np.concatenate([np.arange(n), np.arange(n)[::-1]])
    poses = np.column_stack([2.0 * place, np.where(keys >= n, 15.0, 0.0), np.zeros(2 * n)])
    desc = places[place]
    ok = np.ones(2 * n, dtype=bool)
    ungated = rc.candidates(desc, ok, keys, along, replace(cfg, drift=np.inf), None, poses, reach)
    gated = rc.candidates(desc, ok, keys, along, cfg, None, poses, reach)
    bound = 15.0 / cfg.drift - reach[0]
    assert gated and len(gated) < len(ungated)
    assert all(along[b] - along[a] >= bound / reach[1] for a, b, _, _ in gated)
    assert {(a, b) for a, b, _, _ in ungated if along[b] - along[a] >= bound / reach[1]} == {
        (a, b) for a, b, _, _ in gated
    }
    assert all(place[a] == place[b] for a, b, _, _ in gated)
    assert rc.any_within_drift(keys, poses, along, cfg, reach, max_pairs=4 * n * n)
    # a return 20% farther off than the widest pair the gate lets through: nothing can pass
    far = poses.copy()
    far[n:, 1] = 1.2 * cfg.drift * (reach[0] + reach[1] * along[-1])
    assert not rc.any_within_drift(keys, far, along, cfg, reach, max_pairs=4 * n * n)
    assert rc.candidates(desc, ok, keys, along, cfg, None, far, reach) == []


def test_held_spectra_and_blocked_gate_give_the_plain_answers() -> None:
    """The speed-ups of session 22 give, to the bit, what they replace: the refs' spectra
    computed once for the log against per query (`spectra_bytes` 0), the same distances
    and the same candidates; the drift gate walked in blocks of rows over the earlier keys
    only against the whole square at once, the same answer, revisit or none."""
    cfg = replace(rc.RecognitionConfig(), drift=np.inf)
    rng = np.random.default_rng(5)
    n = 60
    places = (rng.random((n, cfg.rings, cfg.sectors)) < 0.3) * rng.integers(1, 30, (n, 1, 1))
    places = places.astype(np.uint8)
    held = rc.spectra(places)
    for q in (0, 17, 59):
        near = np.sort(rng.choice(n, 25, replace=False))
        plain = rc.shift_distances(places[q], places[near])
        assert plain.min() < 1.0  # not all empty: the test compares numbers
        assert np.array_equal(
            plain, rc.shift_distances(places[q], None, (held[0][near], held[1][near]))
        )
        # the query's own spectra taken from the stack (session 26): the same as its own
        alone = rc.spectra(places[q])
        assert np.array_equal(alone[0], held[0][q]) and np.array_equal(alone[1], held[1][q])
        from_held = rc.shift_distances(
            places[q], None, (held[0][near], held[1][near]), (held[0][q], held[1][q])
        )
        assert np.array_equal(plain, from_held)
    keys = np.arange(2 * n)
    along = 2.0 * keys
    place = np.concatenate([np.arange(n), np.arange(n)[::-1]])
    desc = places[place]
    ok = np.ones(2 * n, dtype=bool)
    poses = np.column_stack([2.0 * place, np.zeros(2 * n), np.zeros(2 * n)])
    once = rc.candidates(desc, ok, keys, along, cfg, None, poses)
    each = rc.candidates(desc, ok, keys, along, replace(cfg, spectra_bytes=0), None, poses)
    assert len(once) > 10 and once == each
    gated = replace(cfg, drift=4.0)
    reach = (1.0, 0.03)
    for off in (0.0, 15.0, 60.0, 200.0):
        shifted = poses.copy()
        shifted[n:, 1] = off
        answers = {
            rc.any_within_drift(keys, shifted, along, gated, reach, rows=rows)
            for rows in (1, 7, 64, 4 * n)
        }
        # the whole square at once, as before
        ka, xy = along[keys], shifted[keys, :2]
        path = ka[:, None] - ka[None, :]
        apart = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
        whole = bool(((path > gated.gap) & rc.within_drift(apart, path, gated, reach)).any())
        assert answers == {whole}
    assert rc.any_within_drift(keys, poses, along, gated, reach)
    far = poses.copy()
    far[n:, 1] = 1e4
    assert not rc.any_within_drift(keys, far, along, gated, reach, rows=5)


def test_descriptors_in_chunks_equal_one_keyframe_at_a_time(building: toolkit.Dataset) -> None:
    """`keyframe_descriptors` (the keyframes' maps placed and voxelled in one numba call per
    chunk, described together) gives every keyframe the descriptor `describe` gives its
    `voxel_subsample(local_points(...))`, to the count, whatever the chunk."""
    poses = odometry_poses(building)
    assert poses is not None
    keys = keyframes_of(poses, 0.5, 0.3)
    along = path_length(poses)
    closer = LoopCloser(building.ranges, building.laser)
    cfg = rc.RecognitionConfig()
    lo = np.searchsorted(along[keys], along[keys] - cfg.path, side="left")
    hi = np.searchsorted(along[keys], along[keys] + cfg.path, side="right")
    plain = np.zeros((len(keys), cfg.rings, cfg.sectors), dtype=np.uint8)
    for q in range(len(keys)):
        near = keys[lo[q] : hi[q]]
        near = near[np.linspace(0, len(near) - 1, min(len(near), cfg.scans)).astype(np.int64)]
        pts = voxel_subsample(closer.local_points(int(keys[q]), near, poses), cfg.voxel)
        assert len(pts) >= cfg.min_points
        plain[q] = rc.describe(pts, cfg)
    assert len(keys) > 50 and plain.sum() > 0
    for chunk in (1, 13, 128):
        desc, ok = rc.keyframe_descriptors(closer, keys, poses, along, cfg, chunk=chunk)
        assert ok.all() and np.array_equal(desc, plain)
    # a keyframe whose map is too small is left undescribed
    sparse = replace(cfg, min_points=int(plain[0].sum()) + 1)
    desc, ok = rc.keyframe_descriptors(closer, keys, poses, along, sparse)
    assert not ok.all() and not desc[~ok].any() and np.array_equal(desc[ok], plain[ok])


def _both_headings_judged(
    closer: LoopCloser,
    keys: np.ndarray,
    poses: np.ndarray,
    along: np.ndarray,
    loop_config: LoopConfig,
) -> list[Loop]:
    """`find` as it was before session 22's verify22: both headings verified in full (the
    opposite's tests run and thrown away), the better kept."""
    cfg = rc.RecognitionConfig()
    desc, ok = rc.keyframe_descriptors(closer, keys, poses, along, cfg)
    verify_cfg = replace(loop_config, corridor=False, turn=cfg.turn)
    reach = (loop_config.radius, loop_config.growth)
    out = []
    for a, b, _, heading in rc.candidates(desc, ok, keys, along, cfg, None, poses, reach):
        prediction = np.array([0.0, 0.0, heading])
        loop = closer.verify(a, b, cfg.window, poses, along, keys, verify_cfg, prediction)
        if loop is None:
            continue
        prediction[2] = wrap(heading + np.pi)
        flip = closer.verify(a, b, cfg.window, poses, along, keys, verify_cfg, prediction)
        if flip is not None and flip.score > loop.score:
            loop, flip = flip, loop
        if flip is not None and flip.score > loop_config.max_ambiguity * loop.score:
            loop.accepted = False
        out.append(loop)
    return out


def test_only_the_winning_heading_tested_and_the_opposite_only_if_passed(real: Path) -> None:
    """seattle, drift seed 0 (development), recognition over the front end's trajectory:
    testing only the better heading's match (`LoopCloser.judge`; the opposite's score is all
    that is used of it) gives every pair the loop both headings' full verification gave.
    `opposite_if_passed` (the opposite searched only when the descriptor's heading passes)
    searches less (the pairs refused at once) but is not exact: one loop is lost here."""
    from toolkit.slam.scanmap import scan_to_map

    ds = drifted_carmen(real, "seattle", seed=0)
    poses = scan_to_map(ds).poses
    keys = keyframes_of(poses, SlamConfig().keyframe_distance, SlamConfig().keyframe_angle)
    along = path_length(poses)
    loop_cfg = LoopConfig()
    full = LoopCloser(ds.ranges, ds.laser)
    full.refuse_at_coarse = False  # every verification in full, as before session 26
    old = _both_headings_judged(full, keys, poses, along, loop_cfg)
    new = rc.find(LoopCloser(ds.ranges, ds.laser), keys, poses, along, loop_cfg)
    assert len(old) >= 10 and sum(lp.accepted for lp in old) >= 2
    assert [(lp.a, lp.b, lp.accepted) for lp in old] == [(lp.a, lp.b, lp.accepted) for lp in new]
    # a pair refused at the coarse level (both headings ambiguous: session 26) has the coarse
    # winner's pose and score; every other pair the full verification's
    early = [n.reason.endswith("(coarse level), both headings") for n in new]
    assert sum(early) >= 3
    assert all(
        e or (o.score == n.score and np.array_equal(o.pose, n.pose))
        for o, n, e in zip(old, new, early, strict=True)
    )

    searches = 0
    plain_search = LoopCloser.search_coarse

    class Counted(LoopCloser):
        def search_coarse(self, *args, **kwargs):  # type: ignore[no-untyped-def]
            # each search starts with its coarse level
            nonlocal searches
            searches += 1
            return plain_search(self, *args, **kwargs)

    cfg = replace(rc.RecognitionConfig(), opposite_if_passed=True)
    quick = rc.find(Counted(ds.ranges, ds.laser), keys, poses, along, loop_cfg, cfg)
    refused = sum(not lp.accepted for lp in quick)
    assert refused >= 5
    # not exact: a pair whose descriptor heading is refused is no longer searched turned
    # round, and here one such pair's opposite won and passed: (47, 132) is lost; none gained
    kept = {(lp.a, lp.b) for lp in quick if lp.accepted}
    before = {(lp.a, lp.b) for lp in old if lp.accepted}
    assert kept <= before and before - kept == {(47, 132)}
    # ... a true loop (8 mm, 0.3 deg from the truth's), turned round against the descriptor
    lost = next(lp for lp in old if (lp.a, lp.b) == (47, 132))
    truth = truth_poses(ds)
    assert truth is not None and not is_false_loop(lost, truth) and abs(lost.pose[2]) > 2.5
    # each pair searched once, the accepted (their opposite searched) twice; both for all
    # pairs before
    assert len(old) + sum(lp.accepted for lp in quick) <= searches < 2 * len(old)
