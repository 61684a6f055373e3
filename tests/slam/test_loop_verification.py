"""Loop verification on real logs: what the reference could see (line of sight) and the
ambiguity among those points (docs/journal/maps.md, session 12); a loop anchored on a front-end slip
(session 13); a false loop that is the truth's, and one hidden by parallel corridor axes
(session 19)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.slam.conftest import drifted_carmen
from toolkit.metrics import evaluate
from toolkit.poses import truth_poses
from toolkit.slam.loops import (
    Loop,
    LoopCloser,
    is_false_loop,
)
from toolkit.slam.pipeline import SlamConfig, close_loops
from toolkit.slam.scanmap import MapConfig, scan_to_map


def test_real_orebro_return_to_the_start_is_accepted(real: Path) -> None:
    """orebro (seed 0) ends where it began: scans 227-232 match scans 0-3 within 0.2 m of the
    truth, but half of their returns fall behind the start's walls, where the start's scans
    never looked; counted as unseen (line of sight) and left out of the ambiguity test too, the
    return passes and ties the end down (ATE 0.32 -> 0.15 m). Either option alone, or the
    default (the field-of-view test), refuses it. On the front end as it was then: the narrow
    refit at scan 213 (session 18) changes the end and the loops found there; and with
    `subcell` off, as found (with it one option alone passes the return too)."""
    ds = drifted_carmen(real, "orebro", seed=0)
    truth = truth_poses(ds)
    assert truth is not None
    before = scan_to_map(ds, MapConfig(narrow_stray=0.0)).poses

    def run(**loop: bool) -> tuple[float, list[Loop]]:
        cfg = SlamConfig()
        cfg = replace(cfg, loop=replace(cfg.loop, **{"subcell": False, **loop}))
        poses, _, _, loops, _, _ = close_loops(ds, before, cfg)
        accepted = [lp for lp in loops if lp.accepted]
        assert not [lp for lp in accepted if is_false_loop(lp, truth)]
        ret = [lp for lp in accepted if lp.a <= 3 and lp.b >= 225]
        return float(evaluate(poses, truth)["ate"]["rmse"]), ret

    ate, ret = run(line_of_sight=True, seen_ambiguity=True)
    assert len(ret) >= 2 and ate < 0.25
    for one in ({"line_of_sight": True}, {"seen_ambiguity": True}, {}):
        ate_off, ret_off = run(**one)
        assert ret_off == [] and ate_off > ate + 0.1


def test_real_freiburg_campus_loops_anchored_on_a_front_end_slip_are_refused(real: Path) -> None:
    """freiburg-campus: the front end puts scan 216 0.5 m and 3.5 deg off its neighbours (seed
    3, the bench's draw 1); a loop in its frame carries the slip (216 -> 1162: 0.50 m, 2.6 deg
    off the truth), and the loops nearby share the local map and agree. Scan 216 fits its own
    local map 0.47 m off (`anchor`). On seed 0 draw 2, 230 -> 1244 (0.53 m, 1.0 deg off) passes
    that test, but the query fits scan 230 alone 0.50 m from where the local map put it
    (`anchor_match`). With both (the default) neither run has a false loop; without the one
    check that refuses it, each has its own (docs/journal/maps.md, session 14). Read as the
    laser's poses (the default since session 34) no false loop is accepted on seed 3 draw 1
    without `anchor` either: the test keeps PARAM's reading (`equal_poses="robot"`; session 34, carry34)."""
    from bench.bench_slam import nudged

    front: dict[tuple[int, int], np.ndarray] = {}

    def false_loops(seed: int, draw: int, **loop: bool) -> set[tuple[int, int]]:
        ds = nudged(drifted_carmen(real, "freiburg-campus", seed, equal_poses="robot"), draw)
        truth = truth_poses(ds)
        assert truth is not None
        if (seed, draw) not in front:
            front[(seed, draw)] = scan_to_map(ds).poses
        cfg = SlamConfig()
        cfg = replace(cfg, loop=replace(cfg.loop, **loop))
        _, _, _, loops, _, _ = close_loops(ds, front[(seed, draw)], cfg)
        return {(lp.a, lp.b) for lp in loops if lp.accepted and is_false_loop(lp, truth)}

    assert false_loops(3, 1) == set()
    assert (216, 1162) in false_loops(3, 1, anchor=False)
    assert false_loops(0, 2) == set()
    assert (230, 1244) in false_loops(0, 2, anchor_match=False)


def test_real_fhw_corridor_loop_on_a_scan_its_local_map_does_not_pin_is_refused(
    real: Path,
) -> None:
    """fhw seed 4: the robot turns 112 deg over scans 55-58 and back; a narrow second fit of
    the front end (session 17, not kept) placed scans 55-62 as below (relative to scan 54),
    scan 57 8 deg off its neighbours by the truth. The query 370 matches 57's local map as a
    corridor loop (inliers 0.73, ambiguity 0.90) that carries that 8 deg. Scan 57 fits its own
    local map with only 0.70 of its returns (`anchor_agree` 0.75, the default since session
    18): refused; 56 -> 370, whose anchor its map agrees with, is right and kept
    (docs/journal/maps.md, session 17)."""
    from toolkit.se2 import compose
    from toolkit.slam.loops import LoopCloser, LoopConfig, loop_truth_error, path_length
    from toolkit.slam.pipeline import keyframes_of

    ds = drifted_carmen(real, "fhw", seed=4)
    truth = truth_poses(ds)
    assert truth is not None
    poses = scan_to_map(ds).poses
    narrow = np.array(
        [
            [0.304, 0.1501, -0.0818],
            [0.2501, 0.0501, -0.6567],
            [0.2834, 0.1101, -1.6254],
            [0.2592, 0.1164, -2.0523],
            [0.324, -0.0072, -0.9112],
            [0.3421, 0.033, -0.5214],
            [0.327, -0.0492, 0.0722],
            [0.1944, 0.0223, -0.309],
        ]
    )
    poses[55:63] = compose(np.broadcast_to(poses[54], (8, 3)), narrow)
    keys = keyframes_of(poses, 0.5, 0.3)
    along = path_length(poses)
    assert 56 in keys and 57 in keys

    def verify(a: int, agree: float) -> Loop:
        cfg = replace(LoopConfig(), anchor_agree=agree)
        found = LoopCloser(ds.ranges, ds.laser, cfg).verify(a, 370, 3.0, poses, along, keys)
        assert found is not None and found.axis is not None  # a corridor loop
        return found

    off = verify(57, 0.0)  # the test off: the loop passes and is false
    assert off.accepted and is_false_loop(off, truth)
    assert loop_truth_error(off, truth)[1] > 7.0
    refused = verify(57, LoopConfig().anchor_agree)  # the default
    assert not refused.accepted and refused.reason.startswith("anchor: scan 57 fits its local")
    kept = verify(56, LoopConfig().anchor_agree)
    assert kept.accepted and not is_false_loop(kept, truth)


def test_real_freiburg_campus_false_loop_at_scan_1245_is_the_truths(real: Path) -> None:
    """freiburg-campus seed 28, the bench's draw 2: the corridor loop 241 -> 1245 is 0.56 m
    across its axis off the corrected log's poses (the truth), a false loop by #20's measure.
    But scan 1245's own returns, matched against 241's local map placed by the truth, fit
    within 0.05 m (across) of the loop and 0.89 m from where the truth puts 1245; 243 -> 1249
    beside it fits its truth within 0.15 m. The truth zigzags there: scan 1245 fits its own
    truth-placed neighbours 0.58 m off (1243 0.57, 1247 0.70), 1251 within 0.1 m. The loop is
    right by the scans; no test on the loop can refuse it (docs/journal/maps.md, session 19).
    Read as the laser's poses (the default since session 34) the front end differs and the loop
    is refused (inliers 0.46): the test keeps PARAM's reading (`equal_poses="robot"`; session
    34, carry34)."""
    from bench.bench_slam import nudged
    from toolkit.se2 import between, compose
    from toolkit.slam.grid import voxel_subsample
    from toolkit.slam.loops import LoopCloser, LoopConfig, path_length
    from toolkit.slam.pipeline import keyframes_of

    ds = nudged(drifted_carmen(real, "freiburg-campus", seed=28, equal_poses="robot"), 2)
    truth = truth_poses(ds)
    assert truth is not None
    poses = scan_to_map(ds).poses
    keys = keyframes_of(poses, 0.5, 0.3)
    cfg = LoopConfig()
    closer = LoopCloser(ds.ranges, ds.laser, cfg)
    loop = closer.verify(241, 1245, 3.0, poses, path_length(poses), keys)
    assert loop is not None and loop.accepted and loop.axis is not None
    assert is_false_loop(loop, truth)

    along = path_length(truth)

    def fit_in_truth(a: int, b: int) -> np.ndarray:
        """Scan b's own returns matched against a's local map placed by the truth, from the
        truth's relative pose: where they fit (a's frame)."""
        near = np.nonzero(np.abs(along - along[a]) <= cfg.reference_path)[0]
        ref = closer.local_points(a, near, truth)
        rel = between(truth[a], truth[b])
        own = voxel_subsample(closer.local_points(b, np.array([b]), truth), cfg.query_voxel)
        found = closer._refit(ref, own[closer.seen(own, rel, a, near, truth)], rel, cfg)
        assert found is not None and found[1] > 0.7
        return compose(rel, found[0])

    fixed = fit_in_truth(241, 1245)
    off = between(fixed, loop.pose)
    u = loop.free_axis()
    assert u is not None
    assert abs(off[0] * u[1] - off[1] * u[0]) < 0.05  # the loop: where 1245's returns fit
    assert np.hypot(*between(between(truth[241], truth[1245]), fixed)[:2]) > 0.7
    assert np.hypot(*between(between(truth[243], truth[1249]), fit_in_truth(243, 1249))[:2]) < 0.15

    def own_fit(k: int) -> float:
        refs = np.nonzero(np.abs(along - along[k]) <= cfg.reference_path)[0]
        found = closer.anchor_consistency(k, refs, truth, cfg)
        assert found is not None
        return float(np.hypot(*found[0][:2]))

    assert own_fit(1245) > 0.5 and own_fit(1247) > 0.5 and own_fit(1251) < 0.1


def test_real_infinite_corridor_loop_hidden_by_parallel_axes_is_inconsistent(real: Path) -> None:
    """infinite-corridor seed 29 draw 0: the corridor loop 44 -> 768 is 2.6 deg off (0.51 m
    across); its two neighbours' axes lie 1.5 and 3.2 deg from its own, and with each spreading
    100 m along its axis their cycles leave it free across too: they agree. With 2 m of along
    spread in the consistency test (`consistency_along`) both disagree and it is dropped;
    44 -> 756, right, is kept. Scan 44's agreement with its local map (`anchor_agree`, the
    default) refuses both, so the test runs with that off, and with the candidates by appearance
    off (with them the pairs around scan 756 are other ones; docs/journal/maps.md, session 19),
    and `corridor_slide` off (session 21), to look at the consistency test alone; and with
    the coarse corridor axis (`corridor_ridge` off): the ridge's axis (the default since session
    41) alone puts 44 -> 768 within 0.5 m of the truth."""
    from bench.bench_slam import nudged

    ds = nudged(drifted_carmen(real, "infinite-corridor", seed=29), 0)
    truth = truth_poses(ds)
    assert truth is not None
    before = scan_to_map(ds).poses

    def loops(**loop: float) -> dict[tuple[int, int], Loop]:
        cfg = SlamConfig()
        cfg = replace(
            cfg,
            loop=replace(
                cfg.loop,
                anchor_agree=0.0,
                recognition=False,
                corridor_slide=0.0,
                **{"corridor_ridge": 0.0, **loop},
            ),
        )
        return {(lp.a, lp.b): lp for lp in close_loops(ds, before, cfg)[3]}

    ridge = loops(corridor_ridge=SlamConfig().loop.corridor_ridge)[(44, 768)]
    assert ridge.accepted and not is_false_loop(ridge, truth)
    off = loops()
    assert off[(44, 768)].accepted and is_false_loop(off[(44, 768)], truth)
    on = loops(consistency_along=2.0)
    assert not on[(44, 768)].accepted and on[(44, 768)].reason.startswith("inconsistent")
    assert on[(44, 756)].accepted and not is_false_loop(on[(44, 756)], truth)
    assert not [lp for lp in on.values() if lp.accepted and is_false_loop(lp, truth)]


def test_real_infinite_corridor_loop_matched_on_another_stretch_slides(real: Path) -> None:
    """infinite-corridor seed 33 draw 1: the corridor loop 42 -> 768 takes its along position
    from the drifted trajectory, which puts 768 next to 42; by the truth it is 12.8 m further
    along, so the match set 768's query on another stretch of the corridor, whose 1-2 deg
    bend leaves the loop 0.57 m across from the truth. The full loops nearby (50 -> 764) put
    768 12.8 m along in the optimum; with `corridor_slide` 4 m (the default) the loop is
    withdrawn there ("slid"), and the run has no false loop; off, 42 -> 768 is accepted and
    false (docs/journal/maps.md, session 21). Both with the coarse corridor axis
    (`corridor_ridge` off): the ridge's axis (the default since session 41) alone keeps
    42 -> 768 within 0.5 m of the truth, slide or no slide. All with `subcell` off, as found
    (with it 42 -> 768 is withdrawn by its residual even with the slide test off)."""
    from bench.bench_slam import nudged

    ds = nudged(drifted_carmen(real, "infinite-corridor", seed=33), 1)
    truth = truth_poses(ds)
    assert truth is not None
    front = scan_to_map(ds)
    assert front.matches is not None
    step_cov = front.matches.covariance

    def loops(slide: float, ridge: float = 0.0) -> dict[tuple[int, int], Loop]:
        cfg = SlamConfig()
        cfg = replace(
            cfg,
            loop=replace(cfg.loop, corridor_slide=slide, corridor_ridge=ridge, subcell=False),
        )
        out = close_loops(ds, front.poses, cfg, step_cov)[3]
        return {(lp.a, lp.b): lp for lp in out}

    ridge = loops(0.0, SlamConfig().loop.corridor_ridge)[(42, 768)]
    assert ridge.accepted and not is_false_loop(ridge, truth)
    off = loops(0.0)
    assert off[(42, 768)].accepted and is_false_loop(off[(42, 768)], truth)
    on = loops(SlamConfig().loop.corridor_slide)
    assert not on[(42, 768)].accepted and on[(42, 768)].reason.startswith("slid")
    assert not [lp for lp in on.values() if lp.accepted and is_false_loop(lp, truth)]
    accepted = {k for k, lp in on.items() if lp.accepted}
    assert len({k for k, lp in off.items() if lp.accepted} - accepted) <= 3  # 38 -> 764 too


def test_real_pairs_refused_at_the_coarse_level_get_the_full_verifications_verdict(
    real: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """infinite-corridor, drift seed 0 (development), every round: a pair whose coarse level
    alone refuses it (its ambiguity over `max_ambiguity` and no corridor axis:
    `LoopCloser.coarse_refusal`) is not searched at the fine level, and gets the verdict the
    full verification gives it, for the same reason (the ambiguity); every other pair's Loop,
    the accepted loops and the poses are the full verification's to the bit (session 26)."""
    ds = drifted_carmen(real, "infinite-corridor", seed=0)
    before = scan_to_map(ds).poses

    def run(early: bool) -> tuple[np.ndarray, list[Loop]]:
        monkeypatch.setattr(LoopCloser, "refuse_at_coarse", early)
        poses, _, _, loops, _, _ = close_loops(ds, before, SlamConfig())
        return poses, loops

    full_poses, full = run(False)
    poses, loops = run(True)
    assert np.array_equal(poses, full_poses)
    assert [(lp.a, lp.b, lp.accepted) for lp in loops] == [(lp.a, lp.b, lp.accepted) for lp in full]
    coarse = [(lp, f) for lp, f in zip(loops, full, strict=True) if "(coarse level" in lp.reason]
    assert len(coarse) >= 100 and any(lp.recognised for lp, _ in coarse)
    for lp, f in coarse:
        assert not f.accepted and f"ambiguity {f.ambiguity:.2f} >" in f.reason
        assert np.isnan(lp.inliers) and lp.reason.startswith(f"ambiguity {lp.ambiguity:.2f} >")
    for lp, f in zip(loops, full, strict=True):
        if "(coarse level" not in lp.reason:
            assert np.array_equal(lp.pose, f.pose) and lp.reason == f.reason
            assert (lp.score, lp.inliers, lp.ambiguity) == (f.score, f.inliers, f.ambiguity)


def test_real_freiburg_campus_corridor_loop_won_on_its_window_edge_is_refused(real: Path) -> None:
    """freiburg-campus drift seed 72 (docs/journal/maps.md, session 30): the trajectory put scan
    1252 3.8 m short of where scan 241's local map has it, beyond the loop search's +-3 m
    window. The window's best pose lies on its edge, the corridor's ridge cut there (it bends
    into 241's local map) tilts the corridor axis some 65 deg, and the corridor loop is 0.52 m
    across it off the truth. Searched again centred on that winner, the query moves 0.49 m
    across the axis: refused (`edge_check`). The truth's poses, the run's prediction. The
    coarse corridor axis (`corridor_ridge` off) for the refusal's premise: the ridge's axis
    takes 0.04 m off (0.49 m), and the edge test still refuses it."""
    from toolkit.se2 import between
    from toolkit.slam.loops import LoopConfig, path_length
    from toolkit.slam.pipeline import keyframes_of

    ds = drifted_carmen(real, "freiburg-campus", seed=0)
    truth = truth_poses(ds)
    assert truth is not None
    keys, along = keyframes_of(truth, 0.5, 0.3), path_length(truth)

    def verify(cfg: LoopConfig, prediction: np.ndarray) -> Loop:
        closer = LoopCloser(ds.ranges, ds.laser, cfg)
        loop = closer.verify(241, 1252, 3.0, truth, along, keys, prediction=prediction)
        assert loop is not None
        return loop

    run = np.array([0.31, -0.67, -0.16])  # seed 72's prediction, 241's frame
    off = verify(LoopConfig(edge_check=0.0, corridor_ridge=0.0), run)
    assert off.accepted and off.axis is not None and is_false_loop(off, truth)
    assert not verify(LoopConfig(corridor_ridge=0.0), run).accepted
    on = verify(LoopConfig(), run)
    assert not on.accepted and on.reason.startswith("edge: searched again")
    # seed 67's 241 -> 1250, its truth 0.13-0.33 m beyond the window: on the edge too, but the
    # second search stays within 0.3 m across the axis; kept, right
    edge = between(truth[241], truth[1250]) - np.array([2.5, 3.33, 0.0])
    closer = LoopCloser(ds.ranges, ds.laser, LoopConfig())
    kept = closer.verify(241, 1250, 3.0, truth, along, keys, prediction=edge)
    assert kept is not None and kept.accepted and not is_false_loop(kept, truth)
    assert np.abs(kept.pose[:2] - edge[:2]).max() > 2.8  # its winner: the window's edge


def test_real_freiburg_campus_loop_on_a_turned_scan_is_refused(real: Path) -> None:
    """freiburg-campus drift seed 73 (docs/journal/maps.md, session 30): the front end put scan
    216 0.55 m back and 3.6 deg turned against its neighbours (206-227 all alike), and the full
    loop 216 -> 1161, in 216's frame, carries it (0.54 m, 3.8 deg off the truth here). Scan
    216 fits its local map 0.20 m off, under `anchor_slip`, but 3.4 deg turned: refused by
    `anchor_slip_turn` (0.05 rad). Scan 216 agrees poorly with any placement: in the truth
    it fits its neighbours 0.70 m off (the loop is 0.16 m / 0.8 deg from 216 placed there)."""
    from toolkit.se2 import compose
    from toolkit.slam.loops import LoopConfig, path_length
    from toolkit.slam.pipeline import keyframes_of

    ds = drifted_carmen(real, "freiburg-campus", seed=0)
    truth = truth_poses(ds)
    assert truth is not None
    keys = keyframes_of(truth, 0.5, 0.3)
    slipped = truth.copy()
    slipped[216] = compose(truth[216], np.array([-0.548, -0.197, 0.0637]))  # seed 73's

    def verify(cfg: LoopConfig, poses: np.ndarray) -> Loop:
        loop = LoopCloser(ds.ranges, ds.laser, cfg).verify(
            216, 1161, 3.0, poses, path_length(poses), keys
        )
        assert loop is not None
        return loop

    off = verify(LoopConfig(anchor_slip_turn=0.0), slipped)
    assert off.accepted and off.axis is None and is_false_loop(off, truth)
    on = verify(LoopConfig(reanchor=False), slipped)
    assert not on.accepted and on.reason.endswith("deg turned")
    # the truth's 216 is no better: its returns fit its truth-placed neighbours 0.70 m and 3.8
    # deg from it (where the front end put it), and the loop is refused on it too
    truthful = verify(LoopConfig(reanchor=False), truth)
    assert not truthful.accepted and truthful.reason.startswith("anchor: scan 216 fits")


def test_real_freiburg_campus_loop_on_a_turned_scan_is_reanchored_on_a_neighbour(
    real: Path,
) -> None:
    """`reanchor` (docs/journal/maps.md, session 31): the loop `anchor_slip_turn` refuses is
    matched against the whole local map, so only scan a's own frame carries a's slip; put in
    the frame of a's nearest keyframe that fits that map, it is right. Seed 73's slip of scan
    216 (the test above): 216 -> 1161, 0.5 m / 3 deg off the truth in 216's frame, is accepted
    on a neighbour and within 0.15 m and 1.5 deg of the truth. Seed 139's corridor loop 245 ->
    1253 (scan 245 fits its local map 3.4 deg turned: the front end's slip, put on the truth's
    poses): refused without `reanchor`, 3.4 deg off the truth when accepted in 245's frame
    (`anchor_slip_turn` 0), 0.5 deg or less on a neighbour."""
    from toolkit.se2 import between, compose
    from toolkit.slam.loops import LoopConfig, loop_truth_error, path_length
    from toolkit.slam.pipeline import keyframes_of

    ds = drifted_carmen(real, "freiburg-campus", seed=0)
    truth = truth_poses(ds)
    assert truth is not None
    keys = keyframes_of(truth, 0.5, 0.3)

    def verify(cfg: LoopConfig, poses: np.ndarray, a: int, b: int) -> Loop:
        loop = LoopCloser(ds.ranges, ds.laser, cfg).verify(
            a, b, 3.0, poses, path_length(poses), keys
        )
        assert loop is not None
        return loop

    slipped = truth.copy()
    slipped[216] = compose(truth[216], np.array([-0.548, -0.197, 0.0637]))  # seed 73's
    on = verify(LoopConfig(), slipped, 216, 1161)
    assert on.accepted and on.anchored == 216 and on.a != 216 and on.pair == (216, 1161)
    m, deg = loop_truth_error(on, truth)
    assert m < 0.15 and deg < 1.5
    # seed 139: scan 245 fits its local map at (-0.16, -0.20, +3.4 deg): put it where it slipped
    fit = np.array([-0.16, -0.20, np.radians(3.4)])
    slipped = truth.copy()
    slipped[245] = compose(truth[245], between(fit, np.zeros(3)))
    refused = verify(LoopConfig(reanchor=False), slipped, 245, 1253)
    assert not refused.accepted and refused.reason.endswith("deg turned")
    carried = verify(LoopConfig(anchor_slip_turn=0.0, reanchor=False), slipped, 245, 1253)
    assert carried.accepted and loop_truth_error(carried, truth)[1] > 3.0
    kept = verify(LoopConfig(), slipped, 245, 1253)
    assert kept.accepted and kept.anchored == 245 and kept.a != 245 and kept.axis is not None
    m, deg = loop_truth_error(kept, truth)
    assert m < 0.15 and deg < 0.5


def test_real_freiburg_campus_keeps_its_reanchored_loop(real: Path) -> None:
    """freiburg-campus drift seed 139 (the lead's held-out run of session 30, development since),
    PARAM's reading: `anchor_slip_turn` refused the right corridor loop 245 -> 1253 (scan 245
    fits its local map 3.4 deg turned) and the run lost its neighbours' loops with it (ATE 0.31
    -> 0.43 m with the rule on). With `reanchor` (the default) the loop is kept on a neighbour
    of 245, the run has no false loop, and its ATE is back under 0.33 m (0.304;
    docs/journal/maps.md, session 31). Read as the laser's poses (the default since session
    34) seed 139 re-anchors nothing (frame33); drift seed 54 carries the case in that reading:
    the corridor loop 248 -> 1256 is kept on scan 249 (0.09 m, 0.04 deg off the truth), no
    false loop, ATE 0.262 m (session 34, carry34)."""
    from toolkit.slam.run import slam_trajectory

    ds = drifted_carmen(real, "freiburg-campus", seed=54)
    truth = truth_poses(ds)
    assert truth is not None
    result, run = slam_trajectory(ds, slam=SlamConfig())
    moved = [lp for lp in run.loops if lp.pair == (248, 1256)]
    assert len(moved) == 1 and moved[0].accepted and moved[0].a != 248
    assert not [lp for lp in run.loops if lp.accepted and is_false_loop(lp, truth)]
    assert evaluate(result.poses, truth)["ate"]["rmse"] < 0.33


def test_real_freiburg_campus_full_loop_on_a_slipped_query_is_refused(real: Path) -> None:
    """freiburg-campus drift seed 1 (docs/journal/maps.md, session 37, fc446): the front end
    zigzags 0.3-0.4 m along the corridor at scans 1256-1259 (the odometry, 0.02-0.03 m per step
    off the truth there, does not), so the query of scan 1258 (1258 and 1259, 1 m apart) is a
    double image; matched by appearance against 251's and 252's local maps it wins 0.57 / 0.70
    m off the truth (ambiguity 0.83, under 0.85), and the loops agree with the slipped chain and
    with each other, so the consistency test keeps them (with `query_odometry` and
    `query_alone` off; the latter alone refuses 251's). With `query_odometry` (0.35 m, the
    default) both are refused (scan 1259 placed 0.39 m nearer 1258 than the odometry has it):
    no false loop, ATE 0.396 -> 0.352 m."""
    from dataclasses import replace as changed

    from toolkit.poses import odometry_poses
    from toolkit.se2 import between
    from toolkit.slam.run import slam_trajectory

    ds = drifted_carmen(real, "freiburg-campus", seed=1)
    truth, odometry = truth_poses(ds), odometry_poses(ds)
    assert truth is not None and odometry is not None
    # the odometry holds scan 1259 from 1258 where the truth has it
    assert (
        np.hypot(*(between(odometry[1258], odometry[1259]) - between(truth[1258], truth[1259]))[:2])
        < 0.05
    )

    def run(**loop: float) -> tuple[float, list[Loop]]:
        cfg = SlamConfig()
        result, slam = slam_trajectory(ds, slam=changed(cfg, loop=changed(cfg.loop, **loop)))
        return evaluate(result.poses, truth)["ate"]["rmse"], slam.loops

    ate, loops = run(query_odometry=0.0, query_alone=0.0)  # `query_alone` refuses 251's
    false = {lp.pair for lp in loops if lp.accepted and is_false_loop(lp, truth)}
    assert false == {(251, 1258), (252, 1258)}
    ate_on, loops_on = run()  # the default, 0.35 m
    refused = {lp.pair: lp for lp in loops_on if lp.reason.startswith("query: scan 1259")}
    assert set(refused) == {(251, 1258), (252, 1258)}
    assert not [lp for lp in loops_on if lp.accepted and is_false_loop(lp, truth)]
    assert ate_on < ate - 0.02


def test_real_freiburg_campus_seed_446_false_loop_is_the_truths(real: Path) -> None:
    """freiburg-campus drift seed 446 (session 36's one held-out false loop; session 37, fc446):
    the corridor loop 243 -> 1245 is 0.50 m across its axis off the truth. It is session 19's
    and 30's scan 1245 (seeds 19, 28, 77): scan 1245's own returns, matched against 243's local
    map placed by the truth, fit within 0.05 m across of the loop and 0.6 m from where the truth
    puts 1245, and 1245 fits its own truth-placed neighbours 0.5 m off (the corrected log
    zigzags across the corridor at 1242-1249). Right by the scans: no test should refuse it;
    `query_odometry` (full loops only) leaves it. The run with session 36's coarse corridor
    axis (`corridor_ridge` off) and `subcell` off, as found: the ridge's axis leaves the loop
    0.48 m across, under the false-loop bound, the same loop; with `subcell` no loop is false."""
    from toolkit.se2 import between, compose
    from toolkit.slam.grid import voxel_subsample
    from toolkit.slam.loops import LoopConfig, path_length
    from toolkit.slam.run import slam_trajectory

    ds = drifted_carmen(real, "freiburg-campus", seed=446)
    truth = truth_poses(ds)
    assert truth is not None
    coarse_axis = replace(
        SlamConfig(), loop=replace(LoopConfig(), corridor_ridge=0.0, subcell=False)
    )
    _, run = slam_trajectory(ds, slam=coarse_axis)
    false = [lp for lp in run.loops if lp.accepted and is_false_loop(lp, truth)]
    assert [lp.pair for lp in false] == [(243, 1245)]
    loop = false[0]
    u = loop.free_axis()
    assert u is not None  # a corridor loop: not the query test's

    cfg = LoopConfig()
    closer = LoopCloser(ds.ranges, ds.laser, cfg)
    along = path_length(truth)
    near = np.nonzero(np.abs(along - along[243]) <= cfg.reference_path)[0]
    ref = closer.local_points(243, near, truth)
    rel = between(truth[243], truth[1245])
    own = voxel_subsample(closer.local_points(1245, np.array([1245]), truth), cfg.query_voxel)
    found = closer._refit(ref, own[closer.seen(own, rel, 243, near, truth)], rel, cfg)
    assert found is not None and found[1] > 0.7
    fixed = compose(rel, found[0])  # where 1245's returns fit, 243's frame
    off = between(fixed, loop.pose)
    assert abs(off[0] * u[1] - off[1] * u[0]) < 0.05  # the loop is where they fit
    miss = between(rel, fixed)
    assert abs(miss[0] * u[1] - miss[1] * u[0]) > 0.5  # the truth is not
    refs = np.nonzero(np.abs(along - along[1245]) <= cfg.reference_path)[0]
    alone = closer.anchor_consistency(1245, refs, truth, cfg)
    assert alone is not None and np.hypot(*alone[0][:2]) > 0.5


def test_real_freiburg_campus_full_loop_whose_scan_alone_fits_elsewhere_is_refused(
    real: Path,
) -> None:
    """freiburg-campus's corridor at scans 1244-1260 against 237-253 (drift seeds 1 and 562's
    false loops 252 -> 1258 / 1260, docs/journal/maps.md, session 42): one scan there fits
    its revisit's local map at more than one place along, so a query's match rests on where
    the trajectory put its other scans. Placed by the truth, the query of 1258 (1258 and
    1259) matches 251's local map as a full loop 0.16 m off the truth, but 1258's own returns
    fit 0.5 m from that match: `query_alone` (0.2 m, the default) refuses the pair; off, it
    passes. A place where one scan fits where the query does (357 -> 1005) passes either way."""
    from toolkit.slam.loops import LoopConfig, loop_truth_error, path_length
    from toolkit.slam.pipeline import keyframes_of

    ds = drifted_carmen(real, "freiburg-campus", seed=1)
    truth = truth_poses(ds)
    assert truth is not None
    cfg = SlamConfig()
    keys = keyframes_of(truth, cfg.keyframe_distance, cfg.keyframe_angle)
    along = path_length(truth)

    def verify(a: int, b: int, alone: float) -> Loop:
        closer = LoopCloser(ds.ranges, ds.laser, replace(LoopConfig(), query_alone=alone))
        loop = closer.verify(a, b, 0.5, truth, along, keys)
        assert loop is not None and loop.axis is None  # a full loop: the test's
        return loop

    off = verify(251, 1258, 0.0)
    assert off.accepted and loop_truth_error(off, truth)[0] < 0.2
    on = verify(251, 1258, LoopConfig().query_alone)
    assert not on.accepted
    assert on.reason.startswith("query: scan 1258 alone fits")
    assert float(on.reason.split("fits ")[1].split(" m")[0]) > 0.4
    for alone in (0.0, LoopConfig().query_alone):
        assert verify(357, 1005, alone).accepted
