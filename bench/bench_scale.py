"""Scale-out: scan-pair matching throughput on Dask LocalClusters of 1, 2 and 4 workers.

Rows: one per scheduler. `none` is the single-process run (numba's threads over every core);
`local:N` cuts the pairs into chunks (toolkit.scale.CHUNK_PAIRS) and runs them on N worker
processes with one thread each. The log is the simulated building's scans repeated to
50,000 (10,000 with --quick), consecutive pairs seeded by odometry. Figures: pairs/s (median
of repeats, shipping the scans to the workers included), the cluster's start-up and its
first tiny task (each worker process loads the numba kernels from the cache; a fresh
checkout compiles them once per worker), and whether the poses equal the single-process
ones bit for bit. On a shared machine the figures follow the free cores, not the worker count.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

SCHEDULERS = ("none", "local:1", "local:2", "local:4")


def _log(scans: int) -> tuple[np.ndarray, np.ndarray, Any]:
    from toolkit.align import scan as sc
    from toolkit.poses import odometry_poses
    from toolkit.sim import simulate

    ds = simulate("building", seed=0).dataset
    odo = odometry_poses(ds)
    assert odo is not None
    steps = sc.laser_motion(sc.between(odo[:-1], odo[1:]), ds.laser)
    copies = -(-scans // ds.n_scans)
    ranges = np.tile(ds.ranges, (copies, 1))[:scans]
    seeds = np.tile(np.vstack([steps, np.zeros((1, 3))]), (copies, 1))[: scans - 1]
    return np.ascontiguousarray(ranges), seeds, ds.laser


def run(out: Path, quick: bool) -> list[dict[str, Any]]:
    from toolkit.scale import client_for, match_pairs_on

    scans = 10_000 if quick else 50_000
    repeats = 2 if quick else 3
    ranges, seeds, laser = _log(scans)
    rows: list[dict[str, Any]] = []
    reference: np.ndarray | None = None
    for scheduler in SCHEDULERS:
        t0 = time.perf_counter()
        with client_for(scheduler) as client:
            started = time.perf_counter() - t0
            t0 = time.perf_counter()
            match_pairs_on(client, ranges[:50], seeds[:49], laser, chunk=10)  # load the kernels
            first = time.perf_counter() - t0
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                matches = match_pairs_on(client, ranges, seeds, laser)
                times.append(time.perf_counter() - t0)
        if reference is None:
            reference = matches.pose
        seconds = statistics.median(times)
        rows.append(
            {
                "name": f"match {scans} scans",
                "scheduler": scheduler,
                "workers": 0 if scheduler == "none" else int(scheduler.split(":")[1]),
                "pairs": len(matches),
                "seconds": round(seconds, 3),
                "pairs_per_s": round(len(matches) / seconds),
                "cluster_start_s": round(started, 2),
                "first_task_s": round(first, 2),
                "equal_to_single_process": bool(np.array_equal(matches.pose, reference)),
            }
        )
    base = next(r["pairs_per_s"] for r in rows if r["scheduler"] == "local:1")
    for row in rows:
        row["speedup_vs_1_worker"] = round(row["pairs_per_s"] / base, 2)
    return rows


if __name__ == "__main__":
    import sys

    for row in run(Path("out/bench"), "--quick" in sys.argv):
        print(row)
