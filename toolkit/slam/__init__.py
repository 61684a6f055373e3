"""Globally consistent maps: sequential matching, loop closure and a GTSAM pose graph.

from toolkit.slam import run_slam
result = run_slam(ds)          # SlamResult: .poses (after loops), .before, .loops, ...
"""

from __future__ import annotations

import time

from toolkit.align import scan as sc
from toolkit.dataset import Dataset
from toolkit.slam.localmap import sequential
from toolkit.slam.pipeline import SlamConfig, SlamResult, close_loops


def run_slam(
    ds: Dataset, config: SlamConfig | None = None, match: sc.MatchConfig | None = None
) -> SlamResult:
    """The default mapper over `ds`: sequential matching, then loops and the pose graph."""
    config = config or SlamConfig()
    t0 = time.perf_counter()
    seq = sequential(ds, match)
    before = seq.poses
    matching = time.perf_counter() - t0
    poses, keys, edges, loops, timings, before = close_loops(ds, before, config)
    timings = {"matching": matching, **timings}
    return SlamResult(
        poses, before, keys, edges, loops, sum(timings.values()), timings, config.to_dict()
    )


__all__ = ["SlamConfig", "SlamResult", "run_slam"]
