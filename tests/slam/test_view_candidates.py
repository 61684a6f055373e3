"""Loop candidates by view (`LoopConfig.view`): a query keyframe with no earlier keyframe
within the position uncertainty gets the nearest one its scan sees within `view` m. DP-SLAM's
loop5 ends 4-6 m behind its start, in the same corridor, facing it: never a candidate by
nearness, a candidate by view, and its match a corridor loop."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import toolkit
from toolkit.slam.loops import KeyIndex, LoopCloser, LoopConfig, candidates, path_length
from toolkit.slam.run import SlamRun, slam_trajectory


@pytest.fixture(scope="module")
def loop5(real: Path) -> tuple[toolkit.Dataset, SlamRun]:
    from importers.carmen import Carmen, CarmenOptions

    ds = Carmen().read([real / "dpslam_loop5" / "loop5.log"], CarmenOptions())
    return ds, slam_trajectory(ds)[1]


def _returns(
    run: SlamRun, along: np.ndarray, pairs: list[tuple[int, int, float]]
) -> list[tuple[int, int, float]]:
    """The pairs from the last 3 m of the path to its first 2 m: the return to the start."""
    return [p for p in pairs if along[p[1]] > along[-1] - 3 and along[p[0]] < 2]


def test_loop5s_return_is_a_candidate_by_view_only(loop5: tuple[toolkit.Dataset, SlamRun]) -> None:
    ds, run = loop5
    poses, keys = run.before, run.keys
    along = path_length(poses)
    closer = LoopCloser(ds.ranges, ds.laser)
    default = LoopConfig()
    end = keys[along[keys] > along[-1] - 3]
    start = keys[along[keys] < 2]
    gaps = np.hypot(*(poses[end, None, :2] - poses[None, start, :2]).T)
    reach = default.radius + default.growth * along[-1]
    assert gaps.min() > min(reach, default.window) + 1.0  # beyond the uncertainty by > 1 m
    assert not _returns(
        run, along, candidates(keys, poses, along, default, None, closer.sight(poses))
    )
    view = replace(default, view=6.0)
    assert not _returns(run, along, candidates(keys, poses, along, view))  # needs `sees`
    found = _returns(run, along, candidates(keys, poses, along, view, None, closer.sight(poses)))
    assert found
    a, b, radius = found[0]
    assert radius == pytest.approx(min(reach, default.window), abs=0.1)  # the uncertainty's
    loop = closer.verify(a, b, radius, poses, along, keys, view)
    assert loop is not None and loop.fit and loop.axis is not None  # a corridor loop
    assert loop.ambiguity > default.max_ambiguity


def test_sight_sees_through_free_space_not_through_walls(
    loop5: tuple[toolkit.Dataset, SlamRun],
) -> None:
    """A point along a beam before its return is seen, one 0.5 m beyond it (and its
    neighbours' returns) is not, nor one behind the scanner."""
    ds, run = loop5
    closer = LoopCloser(ds.ranges, ds.laser)
    sees = closer.sight(run.before)
    k = 300
    r3 = np.nan_to_num(ds.ranges[k].astype(np.float64), nan=np.inf)
    far = np.maximum(np.maximum(r3[:-2], r3[1:-1]), r3[2:])  # beams 1 .. B-2 and neighbours
    beam = int(np.argmin(far)) + 1
    r = float(far[beam - 1])
    angle = run.before[k, 2] + ds.laser.angles[beam]
    u = np.array([np.cos(angle), np.sin(angle)])
    pts = run.before[k, :2] + np.outer([0.5 * r, r + 0.5, -1.0], u)
    assert sees(k, pts).tolist() == [True, False, False]


def test_view_off_proposes_as_before(loop5: tuple[toolkit.Dataset, SlamRun]) -> None:
    ds, run = loop5
    poses, keys = run.before, run.keys
    along = path_length(poses)
    sees = LoopCloser(ds.ranges, ds.laser).sight(poses)
    cfg = LoopConfig()
    assert KeyIndex(keys, poses, along, cfg, sees).sees is None
    assert candidates(keys, poses, along, cfg, None, sees) == candidates(keys, poses, along, cfg)
