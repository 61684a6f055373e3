"""Loop verification on real logs: what the reference could see (line of sight), the ambiguity
among those points, and the keyframe a loop is attached to (docs/maps.md, session 12)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from tests.slam.conftest import drifted_carmen
from toolkit import se2
from toolkit.metrics import evaluate
from toolkit.poses import truth_poses
from toolkit.slam.loops import (
    Loop,
    LoopCloser,
    LoopConfig,
    is_false_loop,
    loop_truth_error,
    path_length,
)
from toolkit.slam.pipeline import SlamConfig, close_loops, keyframes_of
from toolkit.slam.scanmap import scan_to_map


def test_real_orebro_return_to_the_start_is_accepted(real: Path) -> None:
    """orebro (seed 0) ends where it began: scans 227-232 match scans 0-3 within 0.2 m of the
    truth, but half of their returns fall behind the start's walls, where the start's scans
    never looked; counted as unseen (line of sight) and left out of the ambiguity test too, the
    return passes and ties the end down (ATE 0.32 -> 0.15 m). Either option alone, or the
    default (the field-of-view test), refuses it."""
    ds = drifted_carmen(real, "orebro", seed=0)
    truth = truth_poses(ds)
    assert truth is not None
    before = scan_to_map(ds).poses

    def run(**loop: bool) -> tuple[float, list[Loop]]:
        cfg = SlamConfig()
        cfg = replace(cfg, loop=replace(cfg.loop, **loop))
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


def test_real_a_slip_in_the_reference_map_is_not_passed_on_to_the_loop(real: Path) -> None:
    """`LoopConfig.attach` (an option, off by default: it gave false loops in the bench).
    freiburg-campus on its truth, with a 0.5 m slip put in at scan 259 (every later pose
    moved with it, as a front end's local error moves them): scan 1261's revisit matches the
    returns of the keyframes before the slip in scan 260's local map. Attached to 260 the loop
    carries the slip (0.32 m off the truth); attached to the keyframe whose returns hold most
    of its inliers it does not."""
    ds = drifted_carmen(real, "freiburg-campus", seed=0)
    truth = truth_poses(ds)
    assert truth is not None
    first = 259
    rel = se2.between(np.broadcast_to(truth[first], (len(truth) - first, 3)), truth[first:])
    poses = truth.copy()
    moved = se2.compose(truth[first], np.array([0.5, 0.0, 0.0]))
    poses[first:] = se2.compose(np.broadcast_to(moved, rel.shape), rel)
    keys = keyframes_of(poses, 0.5, 0.3)
    along = path_length(poses)
    errors = {}
    for attach in (False, True):
        closer = LoopCloser(ds.ranges, ds.laser, LoopConfig(attach=attach))
        loop = closer.verify(260, 1261, 2.0, poses, along, keys)
        assert loop is not None and loop.accepted
        errors[attach] = loop_truth_error(loop, truth)[0]
        if attach:
            assert loop.a != 260 and loop.key == (260, 1261)
    assert errors[False] > 0.25
    assert errors[True] < 0.1
