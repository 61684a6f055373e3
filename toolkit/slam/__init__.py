"""Globally consistent maps: sequential matching, loop closure and a GTSAM pose graph.

from toolkit.slam import run_slam
result = run_slam(ds)          # SlamResult: .poses (after loops), .before, .loops, ...

The pipeline (GTSAM, scipy.ndimage) loads on first use of these names, not with the package:
so importing one of its modules (the map writers of `toolkit.slam.render`) does not, and a
map run without loops starts without them.
"""

from __future__ import annotations

import importlib
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from toolkit.align import scan as sc
    from toolkit.dataset import Dataset
    from toolkit.slam.pipeline import SlamConfig, SlamResult


def __getattr__(name: str) -> object:
    """`SlamConfig` and `SlamResult`, from `toolkit.slam.pipeline` on first use."""
    if name in ("SlamConfig", "SlamResult"):
        return getattr(importlib.import_module("toolkit.slam.pipeline"), name)
    raise AttributeError(f"module 'toolkit.slam' has no attribute {name!r}")


def run_slam(
    ds: Dataset, config: SlamConfig | None = None, match: sc.MatchConfig | None = None
) -> SlamResult:
    """The default mapper over `ds`: sequential matching, then loops and the pose graph."""
    # on use: the pipeline loads GTSAM and scipy.ndimage (see the module's docstring)
    from toolkit.slam.localmap import sequential  # noqa: PLC0415
    from toolkit.slam.pipeline import SlamConfig, SlamResult, close_loops  # noqa: PLC0415

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
