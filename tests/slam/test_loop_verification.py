"""Loop verification on real logs: what the reference could see (line of sight) and the
ambiguity among those points (docs/maps.md, session 12)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from tests.slam.conftest import drifted_carmen
from toolkit.metrics import evaluate
from toolkit.poses import truth_poses
from toolkit.slam.loops import (
    Loop,
    is_false_loop,
)
from toolkit.slam.pipeline import SlamConfig, close_loops
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
