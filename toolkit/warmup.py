"""Compile the numba kernels of `toolkit map` and `toolkit label` into numba's on-disk cache
ahead of use.

`python -m toolkit.warmup` (run by `make install`): maps a small simulated building (loops,
corridors, revisits) with the default mapper, with `--no-loops` (the paper's pair matcher)
and by odometry, once more with a heading slip in its odometry (the front end then loses its
fit and searches: kernels no clean log reaches, which the real laserazos log compiled on its
first map), and labels its places from its regions with the default model, in a
temporary directory, through the same code as `toolkit map` and `toolkit label` (the
dataset saved and read back, so the kernels see the arrays' types a user's run gives them).
Each kernel is compiled on its first call and cached (`cache=True`: next to the sources, in
`__pycache__`), so a user's first `toolkit map` after installing loads the kernels instead
of compiling them (about 11 s of an idle machine's 23 s on a 5,000-scan log;
docs/benchmarks.md; `make demo`'s first `toolkit label` 14 s against 1.3 s for its second). A kernel whose source file changes is compiled again on its next use,
whether or not this ran.
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from toolkit.dataset import Dataset


def slipped(ds: Dataset, turn: float = 0.5) -> Dataset:
    """`ds` with its odometry turned by `turn` rad from its middle pose on (the later path
    turned about that pose with it): one step whose heading is `turn` off, as a wheel slip."""
    odo = ds.odometry
    assert odo is not None
    xy, theta = odo[["x", "y"]].to_numpy(copy=True), odo["theta"].to_numpy(copy=True)
    k = len(odo) // 2
    c, s = math.cos(turn), math.sin(turn)
    rel = xy[k:] - xy[k]
    xy[k:] = xy[k] + rel @ np.array([[c, s], [-s, c]])
    theta[k:] += turn
    moved = odo.assign(x=xy[:, 0], y=xy[:, 1], theta=theta)
    return replace(ds, odometry=moved)


def warm_up(scans: int = 1200) -> dict[str, float]:
    """Run the map and label commands' code on a simulated building of `scans` scans; seconds
    per run."""
    import toolkit  # noqa: PLC0415  (on use, as every command)
    from toolkit.features.run import label_run  # noqa: PLC0415
    from toolkit.mapping import map_run  # noqa: PLC0415
    from toolkit.sim import simulate  # noqa: PLC0415

    seconds: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="toolkit-warmup-") as tmp:
        data = Path(tmp) / "building"
        sim = simulate("building", seed=0, scans=scans)
        toolkit.save(sim.dataset, data)
        for name, method, loops in (
            ("map (scan-to-map, loops)", "gaussian", True),
            ("map --no-loops", "gaussian", False),
            ("map --method odometry", "odometry", False),
        ):
            t0 = time.perf_counter()
            map_run(data, Path(tmp) / f"run-{len(seconds)}", method, loops=loops)
            seconds[name] = time.perf_counter() - t0
        t0 = time.perf_counter()
        toolkit.save(slipped(sim.dataset), Path(tmp) / "slipped")
        map_run(Path(tmp) / "slipped", Path(tmp) / "run-slipped", "gaussian")
        seconds["map (a heading slip: the front end's search)"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        label_run(data, Path(tmp) / "labels", sim.regions)
        seconds["label"] = time.perf_counter() - t0
    return seconds


def main() -> None:
    os.environ.setdefault("TOOLKIT_NO_PROGRESS", "1")
    t0 = time.perf_counter()
    for name, s in warm_up().items():
        print(f"toolkit.warmup: {name} {s:.1f} s", file=sys.stderr)
    print(
        f"toolkit.warmup: numba kernels cached in {time.perf_counter() - t0:.1f} s", file=sys.stderr
    )


if __name__ == "__main__":
    main()
